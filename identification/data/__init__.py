"""Measured and generated motion as data: the dataset format, end caps to rod states."""
