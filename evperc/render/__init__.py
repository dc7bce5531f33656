"""Pictures of evperc outputs: pignistic colour, decision maps, traces."""
