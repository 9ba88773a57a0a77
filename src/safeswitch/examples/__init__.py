"""Case studies of the framework on plants other than the embedded simulator
(:mod:`safeswitch.examples.highway`: highway-env)."""
