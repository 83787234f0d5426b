"""Custom GTSAM factors of gtsam_rotid (filled by the estimation-core issue)."""
