"""Pure codecs for the ACB-3 board's wire formats (CAN frames, UART packets).

Nothing in this package does I/O: every function maps bytes or numpy arrays to
typed records, and bad bytes become typed errors, never exceptions.
"""
