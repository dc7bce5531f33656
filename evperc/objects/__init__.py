"""After the step: what the frame's decisions say of points and objects — per-point labels
(:mod:`evperc.objects.point_labels`), clusters and tracks of moving and stopped objects."""
