"""MCTrack core: data types, BaseVersion I/O, costs, Kalman filters and the tracker (no rerun)."""
