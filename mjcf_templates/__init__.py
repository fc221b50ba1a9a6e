"""MJCF templates the physics checks fill in (`factory.physics.collide`), shipped as package data
and read through `importlib.resources`, so an installed wheel finds them as a checkout does."""
