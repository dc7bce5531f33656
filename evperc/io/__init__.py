"""Readers (MCAP logs, map files) and writers (NPZ chunks, manifest)."""
