"""The benchmark generator: MLS-MPM simulation, procedural objects, Mitsuba ground truth."""
