"""Everything that fits a model to data: the tokenizer, generator and muscle-surrogate training commands, the
static-optimization label pass, the muscle-path fitting build step, and the model cards written beside weights.

Library modules keep inference only; these are run by ``biomotion train ...`` and never imported by them."""
