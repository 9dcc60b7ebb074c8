"""A campaign's finished runs on disk (``OUT.partial``): kept as batches finish, read
back on resume.

A :class:`RunStore` keeps the rows on disk as batches finish, so an interrupted
campaign keeps what it finished and a resumed one computes only the rest: the
rows (and so the budget) are those of an uninterrupted campaign.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path

from rwlab.campaign.runs import ROW_VERSION, Campaign, steady_from
from rwlab.errors import ConfigError, FileFormatError

__all__ = ["RunStore", "campaign_key"]


def campaign_key(campaign: Campaign) -> str:
    """A digest of what defines every run except their number (a resume must match it).

    Parameters
    ----------
    campaign : Campaign
        The campaign.

    Returns
    -------
    str
        SHA-256, hexadecimal.
    """
    described = {
        "scenario": dataclasses.asdict(campaign.scenario),
        "dispersions": [dataclasses.asdict(d) for d in campaign.dispersions],
        "duration": campaign.duration,
        "controller": campaign.controller,
        "seed": campaign.seed,
        "rows": ROW_VERSION,
        "steady_after": steady_from(campaign),
        "start": campaign.start,
        "requirement": dataclasses.asdict(campaign.requirement),
    }
    text = json.dumps(described, sort_keys=True, default=_plain)
    return hashlib.sha256(text.encode()).hexdigest()


def _plain(obj):
    return obj.tolist() if hasattr(obj, "tolist") else repr(obj)


class RunStore:
    """A campaign's finished runs on disk, kept as they finish (a partial campaign).

    The folder holds ``campaign.json`` (the campaign's key and description) and
    one ``batch-<first run>.json`` per finished batch, each written atomically;
    ``retries.json`` lists retried batches. JSON keeps every float exactly, so
    rows read back are the rows computed.

    Parameters
    ----------
    folder : path-like
        The store (``OUT/runs`` for ``rwlab attitude montecarlo``).
    campaign : Campaign
    """

    FORMAT = "rwlab.CampaignRuns/1"

    def __init__(self, folder: str | os.PathLike, campaign: Campaign) -> None:
        self.folder = Path(folder)
        self.campaign = campaign
        self.key = campaign_key(campaign)

    def exists(self) -> bool:
        """Whether the folder holds a store.

        Returns
        -------
        bool
        """
        return (self.folder / "campaign.json").is_file()

    def create(self) -> None:
        """Start an empty store (the folder is created)."""
        from rwlab._io import write_json

        c = self.campaign
        write_json(
            self.folder / "campaign.json",
            {
                "format": self.FORMAT,
                "key": self.key,
                "scenario": c.scenario.name,
                "controller": c.controller,
                "duration_s": c.duration,
                "campaign_seed": c.seed,
                "runs": c.runs,
            },
        )

    def check(self) -> None:
        """Refuse a store written by another campaign (other options than this one's)."""
        path = self.folder / "campaign.json"
        head = self._read(path)
        if head.get("format") != self.FORMAT:
            raise FileFormatError(f"{path}: not a campaign's runs ({head.get('format')!r})")
        if head.get("key") != self.key:
            raise ConfigError(
                f"{path}: the kept runs belong to another campaign (scenario "
                f"{head.get('scenario')!r}, controller {head.get('controller')!r}, "
                f"duration {head.get('duration_s')} s, seed {head.get('campaign_seed')}); "
                "resume with the options it was started with"
            )

    def rows(self) -> dict[int, dict]:
        """The kept rows by run index.

        Returns
        -------
        dict of int to dict
        """
        rows: dict[int, dict] = {}
        for path in sorted(self.folder.glob("batch-*.json")):
            for row in self._read(path).get("rows", []):
                rows[int(row["run"])] = row
        return rows

    def add(self, rows: list[dict]) -> None:
        """Keep a finished batch's rows (one file, written atomically).

        Parameters
        ----------
        rows : list of dict
            The batch's rows, each with its ``run``.
        """
        from rwlab._io import write_json

        if rows:
            write_json(self.folder / f"batch-{rows[0]['run']:09d}.json", {"rows": rows})

    def retries(self) -> list[dict]:
        """Retries recorded so far.

        Returns
        -------
        list of dict
        """
        path = self.folder / "retries.json"
        return list(self._read(path).get("retries", [])) if path.is_file() else []

    def lost_workers(self) -> list[dict]:
        """Workers lost so far.

        Returns
        -------
        list of dict
        """
        path = self.folder / "retries.json"
        return list(self._read(path).get("lost_workers", [])) if path.is_file() else []

    def save_retries(self, retries: list[dict], lost_workers: list[dict] | None = None) -> None:
        """Record the retries and lost workers so far.

        Parameters
        ----------
        retries : list of dict
            As :attr:`rwlab.campaign.montecarlo.Execution.retries`.
        lost_workers : list of dict, optional
            As :attr:`rwlab.campaign.montecarlo.Execution.lost_workers`.
        """
        from rwlab._io import write_json

        write_json(
            self.folder / "retries.json",
            {"retries": retries, "lost_workers": list(lost_workers or [])},
        )

    @staticmethod
    def _read(path: Path) -> dict:
        try:
            data = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise FileFormatError(f"{path}: not readable JSON ({exc})") from None
        if not isinstance(data, dict):
            raise FileFormatError(f"{path}: not a campaign's runs file")
        return data
