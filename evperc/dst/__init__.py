"""Belief functions over grids: dense (..., 2**n) mass arrays, subsets as bitmasks."""
