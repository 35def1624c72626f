"""What several commands print about a data set's reconstructions: the samples a run wrote, and the
out-of-distribution summary of a calibrated prediction."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from ..core.errors import NanoctError


def reconstructions(directory: Path) -> dict[str, tuple[Any, int]]:
    """Each reconstruction of the data set at ``directory``: (its creation id, samples done); empty where the data
    set cannot be read (the command itself then says why)."""
    from ..io.store import DataStore

    try:
        store = DataStore.open(directory)
        return {
            n: (store.recons.fingerprint(n)["created"], int(store.reconstruction_done(n).sum()))
            for n in store.reconstruction_names()
        }
    except (NanoctError, OSError, KeyError, ValueError):
        return {}


def written(directory: Path, name: str, before: dict[str, tuple[Any, int]]) -> str:
    """What a reconstruct or predict run did to ``reconstructions/<name>``, against :func:`reconstructions`
    ``before`` it: the samples it wrote, or that it was complete already."""
    after = reconstructions(directory)
    if name not in after:  # nothing to compare with
        return f"wrote reconstructions/{name}"
    created, done = after[name]
    kept = before.get(name)
    new = done - kept[1] if kept is not None and kept[0] == created else done
    if new == 0:
        return f"reconstructions/{name} was complete already ({done} sample{'s' * (done != 1)}); nothing to do"
    return f"wrote reconstructions/{name} ({new} sample{'s' * (new != 1)}; {done} done)"


def ood_line(ood: dict[str, Any] | None, lead: str = "") -> str:
    """An out-of-distribution summary (:func:`nanoct.io.store.ood_brief`): ``lead`` + "2 of 40 flagged: 20, 32;
    checks std, scan"; empty without one."""
    if not ood:
        return ""
    flagged = ood["flagged"]
    which = f": {', '.join(map(str, flagged[:10]))}{' ...' if len(flagged) > 10 else ''}" if flagged else ""
    left = f"; {len(ood['unchecked'])} left out by footprint (mean too noisy)" if ood["unchecked"] else ""
    return f"{lead}{len(flagged)} of {ood['checked']} flagged{which}; checks {', '.join(ood['checks'])}{left}"


def print_ood(directory: Path, name: str) -> None:
    """Print the out-of-distribution summary (:func:`ood_line`) of ``reconstructions/<name>``, where it has one."""
    from ..io.store import DataStore, ood_brief

    try:
        ood = ood_line(ood_brief(DataStore.open(directory).reconstruction_note(name, "ood")).get("ood"))
    except (NanoctError, OSError, KeyError, ValueError):  # nothing to summarise
        ood = ""
    if ood:
        typer.echo(f"out-of-distribution check of reconstructions/{name} (every image so far): {ood}")
