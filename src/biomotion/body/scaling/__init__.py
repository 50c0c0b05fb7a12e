"""Scaling a body model to a person: per-body factors as OpenSim's ScaleTool applies them (`bodies`), factors from
ANSUR II segment measures (`segments`), and a whole model scaled to a person's stature and mass (`stature`)."""
