"""The application layer: the ``tensegrity-sr`` command line, the demo and the asset builder.

It imports :mod:`tensegrity_env`, :mod:`identification` and :mod:`policies`; nothing imports it.
"""
