"""qpik.batch: the same tasks, limits and controllers over N worlds of one model."""
