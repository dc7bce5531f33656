"""Geometry and maps: the working CRS, geo-referencing, map files, the map prior grid, the
scrolling window."""
