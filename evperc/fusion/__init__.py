"""The per-frame fusion (docs/method.md §5–§6): the numpy twin (:mod:`evperc.fusion.twin`),
the kernel generator (:mod:`evperc.fusion.codegen`), the generated kernel
(:mod:`evperc.fusion.kernel`) and the step the runner calls (:mod:`evperc.fusion.fused`)."""
