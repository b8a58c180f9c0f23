"""Visual front end: images -> observations (numpy + OpenCV; never gtsam or rerun)."""
