"""Package exports imported on first use, so that importing a package stays fast.

Torch, MuJoCo and Stable-Baselines3 take seconds to import; a package ``__init__``
lists what users import from it and pays for a module only when a name from it is
used (PEP 562 module ``__getattr__``)::

    __all__, __getattr__ = lazy_exports(__name__, {"Model": "tensegrity_env.model"})
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(
    package: str, exports: Mapping[str, str]
) -> tuple[list[str], Callable[[str], Any]]:
    """``__all__`` (sorted names) and a module ``__getattr__`` for ``package``.

    ``exports`` maps each public name to the module defining it; the first access
    imports that module and caches the value in the package's namespace.
    """

    def __getattr__(name: str) -> Any:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        setattr(sys.modules[package], name, value)
        return value

    return sorted(exports), __getattr__
