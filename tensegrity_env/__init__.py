"""tensegrity_env package."""
