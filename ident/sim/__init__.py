"""The simulated world: flexible-joint plant, withheld effects, a friction model along a velocity
profile, campaign writer."""
