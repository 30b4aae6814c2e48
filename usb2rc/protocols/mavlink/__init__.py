"""MAVLink: its decoder and field values (`codec`, through pymavlink), its channels, engine
and line session (`session`), its actions (`actions`), and its output (`output`: its registry
row, its own config keys, how it is built).

Before pymavlink is imported (this runs before any module of the package): `hashlib` and
`ssl` load lazily, on their first use. pymavlink's dialects import hashlib for signing only
and mavutil imports ssl for its websocket link only; loaded, the two bring OpenSSL's
libraries into the daemon (~4 MB of RSS, on a Pi that may have 512 MB) for a MAVLink output
that does not sign. One that signs loads hashlib when it is built
(`codec.set_up_signing`), never in a tick.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import threading
import types
from typing import Any

LAZY_MODULES = ("hashlib", "ssl")


_LOADING = threading.Lock()  # one thread loads a stand-in's module; another waits for it
_LOADED: dict[str, types.ModuleType] = {}  # each stand-in's module, once loaded


class LazyModule(types.ModuleType):
    """A module's stand-in in `sys.modules` that loads it at the first use of one of its
    names, then holds the module's names itself (an importer keeps the stand-in). An
    `import` statement reads only `__spec__`, which it has: it loads nothing (the standard
    `importlib.util.LazyLoader` loads at any attribute, `__spec__` too). Loaded once: a name
    the module lacks after that is its AttributeError."""

    def __getattr__(self, name: str) -> Any:
        return getattr(self._module(), name)

    def _module(self) -> types.ModuleType:
        with _LOADING:
            module = _LOADED.get(self.__name__)
            if module is None:
                del sys.modules[self.__name__]
                try:
                    module = importlib.import_module(self.__name__)
                finally:
                    sys.modules[self.__name__] = self
                _LOADED[self.__name__] = module
                self.__dict__.update(module.__dict__)
        return module


def import_lazily(name: str) -> None:
    """`name` in `sys.modules` as a `LazyModule` (unless it is loaded already)."""
    if name in sys.modules:
        return
    spec = importlib.util.find_spec(name)
    if spec is None:
        return
    stand_in = LazyModule(name)
    stand_in.__spec__ = spec
    sys.modules[name] = stand_in


for _name in LAZY_MODULES:
    import_lazily(_name)
