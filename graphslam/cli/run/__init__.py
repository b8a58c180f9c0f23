"""``graphslam run``: :mod:`.command` (parser, dispatch), :mod:`.planar`, :mod:`.spatial`."""
