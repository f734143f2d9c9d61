"""The simulated Black Metal robot (docs/commands/sim.md)."""
