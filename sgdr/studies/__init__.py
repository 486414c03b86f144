"""Studies that answer a question about the method rather than reconstruct an object:
`oracle` (the spring-mass model fitted to the generator's particle tracks, an upper bound on
what identification from images can reach)."""
