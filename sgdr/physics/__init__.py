"""Spring-mass simulator (Eqs. 5-17 of the seed paper): model, parameters, state, forces,
contact, semi-implicit Euler, rollouts and their gradients."""
