"""Lidar sensor models producing {F, O} mass grids (SPEC §3)."""
