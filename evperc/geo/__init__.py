"""Geometry: the working CRS, geo-referencing, the map prior grid, the scrolling window."""
