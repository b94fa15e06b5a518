"""The air the vehicles fly in: mean wind, Dryden turbulence and discrete gusts."""
