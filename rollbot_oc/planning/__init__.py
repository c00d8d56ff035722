"""Planning on the optimal-control layer: Rollbot's model and limits on it, minimum-time legs, orbit entries and
plans through gates."""
