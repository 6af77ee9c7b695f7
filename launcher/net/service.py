"""A service this node serves (roscpp's ServicePublication): its types, and its handler's answer to one request
as the reply's bytes."""

from __future__ import annotations

from collections.abc import Callable

from launcher.net.tcpros import encode_service_response


class ServiceServer:
    """A service we serve: `handler(request_bytes) -> response_bytes`, raising to report failure."""

    # (a plain class: `dataclasses` would be imported at every launch's start for it, ~0.15 MB kept)
    __slots__ = ("name", "type_name", "md5sum", "request_type", "response_type", "callerid", "handler")

    def __init__(self, name: str, type_name: str, md5sum: str, request_type: str, response_type: str,
                 callerid: str, handler: Callable[[bytes], bytes]):
        self.name = name
        self.type_name = type_name
        self.md5sum = md5sum
        self.request_type = request_type
        self.response_type = response_type
        self.callerid = callerid
        self.handler = handler

    def respond(self, request: bytes) -> bytes:
        """The reply to one request, as sent: the handler's response, or the reason it failed (the client gets it,
        the server carries on)."""
        try:
            return encode_service_response(True, self.handler(request))
        except Exception as exc:  # the service failed: the client gets the reason, we carry on
            return encode_service_response(False, str(exc).encode("utf-8"))
