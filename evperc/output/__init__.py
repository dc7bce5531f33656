"""The output of a run (docs/output-format.md): the writer, the NPZ chunks, the mass tiles,
the manifest, the reader (``evperc.load``) and the Foxglove export."""
