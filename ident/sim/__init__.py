"""The simulated world: flexible-joint plant, withheld effects, campaign writer."""
