"""Tables and figures shared by identification, discovery and the experiments."""
