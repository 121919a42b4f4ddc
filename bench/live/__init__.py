"""Live runs: the runner and its rings, and setting up sources and recordings from arguments."""
