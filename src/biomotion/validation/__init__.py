"""Validation against OpenSim 4.6 as the oracle (the ``validate`` extra): every ``biomotion validate`` check.

Each check takes a data root laid out like ``../shared/data``, evaluates whatever is present there, names what it
skipped, and returns JSON-able figures. Malformed data raises; absent data is skipped.
"""
