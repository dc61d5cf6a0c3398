"""Subcommands of the tensegrity-sr CLI that belong to policies: train, transfer."""
