"""Time trial: driving plans with the tracking MPC, exploration, the iterative double-GP loop."""
