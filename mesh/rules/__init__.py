"""Rules several processes compute the same way: a run's cost, forward kinematics, how the arm and its
world are drawn, the full-resolution selector, a run as CSV."""
