"""Subcommands of the tensegrity-sr CLI that belong to identification."""

__all__: list[str] = []  # command modules, loaded by tensegrity_sr.cli
