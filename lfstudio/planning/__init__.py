"""Scene planning: the optics of SPEC "The optics" as pure functions, and the plan object."""
