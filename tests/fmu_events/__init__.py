"""A hybrid door FMU (latch, time event, bounce) built from C for the event tests."""
