"""The application layer: the ``tensegrity-sr`` command line, the demo and the asset builder.

It imports :mod:`tensegrity_env`, :mod:`identification` and :mod:`policies`; nothing imports it.
"""

from tensegrity_env.lazy import lazy_exports

__all__, __getattr__ = lazy_exports(__name__, {"main": "tensegrity_sr.cli"})
