"""The run's token file and the master's allow-list, without a launch."""

import os
import stat

import pytest

from launcher.net.allow import AllowList, parse_networks
from launcher.model import token


def test_token_file_is_readable_only_by_its_user(tmp_path):
    secret, path = token.create(str(tmp_path))
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert token.read(path) == secret and len(secret) == 32
    assert token.matches(secret, secret)
    assert not token.matches(secret, secret[:-1] + "x")
    assert not token.matches(secret, None) and not token.matches("", "")
    again, _ = token.create(str(tmp_path))  # a new run in the same directory gets a new token
    assert again != secret and token.read(path) == again


def test_allow_list_admits_given_networks_loopback_and_own_addresses():
    allow = AllowList(["10.1.0.0/16", "192.0.2.77"])
    assert allow.allows("10.1.200.3") and allow.allows("192.0.2.77")
    assert allow.allows("127.0.0.1") and allow.allows("127.0.1.1") and allow.allows("::1")
    assert allow.allows("::ffff:10.1.0.9")  # an IPv4 client on a dual-stack socket
    assert not allow.allows("10.2.0.1") and not allow.allows("203.0.113.9")
    assert not allow.allows("not-an-address")
    from launcher.net.allow import own_addresses
    for network in own_addresses():
        assert allow.allows(str(network.network_address))


def test_bad_network_is_named():
    with pytest.raises(ValueError, match="10.0.0.300/8"):
        parse_networks(["10.0.0.300/8"])
