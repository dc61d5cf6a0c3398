"""Subcommands of the tensegrity-sr CLI that belong to policies: train, transfer."""

__all__: list[str] = []  # command modules, loaded by tensegrity_sr.cli
