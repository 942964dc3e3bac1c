"""Airframe data files (TOML, a unit beside every number)."""
