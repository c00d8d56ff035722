"""Planning on the optimal-control layer: minimum-time legs, orbit entries and plans through gates."""
