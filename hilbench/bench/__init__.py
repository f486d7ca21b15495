"""The bench: config tables, the one place a bench is assembled, sessions, scenarios, recordings,
step tests, sweeps and reports. Importing it imports nothing else (no side effects)."""
