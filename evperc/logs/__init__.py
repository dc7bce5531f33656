"""Log sources: lidar scans with their poses, from every kind of log, behind one reader
interface (:func:`evperc.logs.factory.open_log`)."""
