"""Control: gait, tasks, the MPOPI planner, the probing manoeuvre, the closed loop and its evaluation."""
