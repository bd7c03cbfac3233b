"""GTSAM factors of fgcal's measurement model (probe points, ball centres, poses, joint readings)."""
