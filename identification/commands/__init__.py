"""Subcommands of the tensegrity-sr CLI that belong to identification."""
