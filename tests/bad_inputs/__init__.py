"""The bad-input corpus: every way a user can hand biomotion a wrong file, number or folder (`cases`), and how a
run of one is judged (`runner`). ``python benchmarks/bad_inputs.py`` runs them all; ``tests/test_bad_inputs.py``
the fast ones."""
