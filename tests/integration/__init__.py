"""Integration tests that run external programs (LinuxCNC)."""
