"""roslaunch XML: `load(files, argv)` turns launch files into a `LaunchConfig` (see loader.py)."""

from __future__ import annotations

import gc
import os

from launcher.model.config import LaunchConfig
from launcher.model.errors import LaunchError
from launcher.workspace.packages import PackageIndex
from launcher.xml.arguments import resolve_launch_arguments
from launcher.xml.loader import XmlLoader

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any, Callable, Iterable, Mapping

    from launcher.model.names import AnonNames

__all__ = ["load", "load_arg_docs", "resolve_launch_arguments"]


def load(files: list[str], argv: Iterable[str] = (), *, environ: Mapping[str, str] | None = None,
         packages: Any = None, core: bool = True, args_only: bool = False,
         warn: Callable[[str], None] | None = None, anon_names: AnonNames | None = None) -> LaunchConfig:
    """Load launch files, in order, with command-line `name:=value` args (incl. `__ns:=`).

    `core=False` leaves out roscore's implicit `/rosout` node (as `--dump-params`
    does); `args_only=True` evaluates `<arg>` tags only (`--ros-args`); `warn`
    is called with each warning as it happens (they are also in `config.warnings`);
    `anon_names`: the `$(anon)` names of a run, made again as before by a reload.
    Raises LaunchError.
    """
    if environ is None:
        environ = os.environ
    if packages is None:
        packages = PackageIndex(environ)
    if anon_names is not None:
        anon_names.start_load()
    loader = XmlLoader(environ=environ, packages=packages, argv=argv, args_only=args_only, core=core, warn=warn,
                       anon_names=anon_names)
    # A load allocates tens of thousands of objects and frees almost none of them, and makes no
    # reference cycles worth collecting: the cyclic GC would only rescan them (~10% of a big load).
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        for f in files:
            _load_file(loader, f)
        config = loader.config()
        loader.yaml_cache.save()
        return config
    finally:
        if gc_was_enabled:
            gc.enable()


def _load_file(loader: Any, filename: str) -> None:
    try:
        loader.load_file(filename)
    except RecursionError:
        # the loader follows the nesting of <group>s and <include>s; expat has no depth limit
        raise LaunchError("Invalid roslaunch XML syntax: elements or includes are nested too deeply "
                          "(maximum recursion depth exceeded)", filename) from None


def load_arg_docs(files: list[str], argv: Iterable[str] = (), *, environ: Mapping[str, str] | None = None,
                  packages: Any = None) -> dict[str, tuple[str | None, str | None]]:
    """The top-level `<arg>`s of the last file: name -> (doc, default), for `--ros-args`."""
    if environ is None:
        environ = os.environ
    if packages is None:
        packages = PackageIndex(environ)
    loader = XmlLoader(environ=environ, packages=packages, argv=argv, args_only=True)
    for f in files:
        _load_file(loader, f)
    return dict(loader.root_scope.arg_docs) if loader.root_scope is not None else {}

