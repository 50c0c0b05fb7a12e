"""The refiner's training data root: ../shared/data without opencap/ (kept for testing) and with every second
Bandai-Namco clip (in name order) of the subjects the split rule puts in train or val (the test subjects' clips are
never read by training; retargeting all 664 clips takes 26 min on an idle 2-core machine)."""

import sys
from pathlib import Path

from biomotion.data.registry import subject_split
from biomotion.data.sources import discover_all

data, view = Path(sys.argv[1]).resolve(), Path(sys.argv[2])
view.mkdir(parents=True)
for entry in data.iterdir():
    if entry.is_dir() and entry.name not in ("opencap", "bandai-namco"):
        (view / entry.name).symlink_to(entry)
specs, _ = discover_all(data, ["bandai-namco"])
by_subject = {}
for spec in specs:
    if subject_split(spec.source, spec.subject) != "test":
        by_subject.setdefault(spec.subject, []).append(spec.path)
for paths in by_subject.values():
    for path in sorted(paths)[::2]:
        target = view / "bandai-namco" / path.parent.name / path.name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.symlink_to(path)
print(sum(len(p[::2]) for p in by_subject.values()), "Bandai-Namco clips linked")
