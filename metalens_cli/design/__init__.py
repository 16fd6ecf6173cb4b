"""Learning the rotation map: parameterisations, losses, the optimisation loop and run directories."""
