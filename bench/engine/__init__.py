"""The live TUI's engine process: the client the screen talks to, the child, the plans."""
