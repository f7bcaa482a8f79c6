"""A campaign's result table: SQLite (the standard library's sqlite3), one row per run, written
and committed as each run ends.

Tables in ``results.sqlite``:

- ``runs``: one row per finished run: ``run`` (index), ``seed``, ``completed``, ``error`` (a
  failed run's, else NULL), one column per dispersed key (named by its key path) and, per
  deputy, ``<deputy>.controller``, ``<deputy>.final_error_m``,
  ``<deputy>.last_orbit_max_error_m``, ``<deputy>.gain_error``,
  ``<deputy>.learned_at_orbits``.  Deterministic: the same campaign gives the same rows.
- ``timing``: ``run``, ``wall_s``, ``worker`` (host name): apart, so that two campaigns' ``runs``
  tables compare equal.
- ``campaign``: ``key``, ``value``: the campaign's identity (``spec``: its JSON; ``file``: the
  campaign file's path) that ``--resume`` checks.

``pandas.read_sql("SELECT * FROM runs ORDER BY run", sqlite3.connect(path))`` reads it.
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Any

from services.ground.campaign.dispersions import CampaignError, CampaignSpec
from services.ground.campaign.run import ROWS_VERSION, deputy_columns

FIXED = ["run", "seed", "completed", "error"]


def identity(spec: CampaignSpec, mode: str) -> str:
    """What a resumed campaign must share with the table's (its run count aside: a campaign
    resumed with more runs extends, every run's draws depending on its index alone), and the
    version of what its rows mean (``ROWS_VERSION``)."""
    camp = {k: v for k, v in spec.campaign.__dict__.items() if k != "runs"}
    disp = [d.__dict__ | {"values": list(d.values)} for d in spec.dispersions]
    return json.dumps(
        {
            "campaign": camp,
            "base": spec.base,
            "dispersions": disp,
            "mode": mode,
            "rows": ROWS_VERSION,
        },
        sort_keys=True,
        default=str,
    )


def columns(spec: CampaignSpec) -> list[str]:
    """The ``runs`` table's columns, in order."""
    names = [d.get("name", "") for d in spec.base.get("deputy", [])]
    return [*FIXED, *(d.key for d in spec.dispersions), *deputy_columns(names)]


def _q(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'


class ResultStore:
    """The result table of one campaign (one writer: the process that runs the campaign)."""

    def __init__(self, path: Path, cols: list[str]) -> None:
        self.path, self.cols = path, cols
        self.con = sqlite3.connect(path)

    @classmethod
    def open(cls, path: Path, spec: CampaignSpec, mode: str, resume: bool) -> ResultStore:
        """Create the table, or reopen it to resume.  CampaignError when it holds finished runs
        and ``resume`` is false, or when it belongs to another campaign."""
        path.parent.mkdir(parents=True, exist_ok=True)
        store = cls(path, columns(spec))
        con, ident = store.con, identity(spec, mode)
        with con:
            con.execute("CREATE TABLE IF NOT EXISTS campaign (key TEXT PRIMARY KEY, value TEXT)")
            cols = ", ".join(
                f"{_q(c)}" + (" INTEGER PRIMARY KEY" if c == "run" else "") for c in store.cols
            )
            con.execute(f"CREATE TABLE IF NOT EXISTS runs ({cols})")
            con.execute(
                "CREATE TABLE IF NOT EXISTS timing "
                "(run INTEGER PRIMARY KEY, wall_s REAL, worker TEXT)"
            )
        old = dict(con.execute("SELECT key, value FROM campaign").fetchall())
        done = len(store.done())
        if old and old.get("spec") != ident:
            store.close()
            raise CampaignError(
                f"{path} holds another campaign's runs (its deployment, "
                "dispersions, seed or mode differ): give another --output"
            )
        if done and not resume:
            store.close()
            raise CampaignError(
                f"{path} already holds {done} finished runs: --resume "
                "continues the campaign, another --output starts afresh"
            )
        with con:
            con.execute("INSERT OR REPLACE INTO campaign VALUES ('spec', ?)", (ident,))
            con.execute("INSERT OR REPLACE INTO campaign VALUES ('file', ?)", (spec.path,))
            con.execute("INSERT OR REPLACE INTO campaign VALUES ('mode', ?)", (mode,))
        return store

    def done(self) -> set[int]:
        """The indices of the runs in the table."""
        return {r[0] for r in self.con.execute("SELECT run FROM runs")}

    def failed(self) -> int:
        """The number of failed runs in the table."""
        return self.con.execute("SELECT count(*) FROM runs WHERE NOT completed").fetchone()[0]

    def write(self, row: dict[str, Any], timing: dict[str, Any]) -> None:
        """Insert one run's row and timing in one transaction (committed on return)."""
        values = [row.get(c) for c in self.cols]
        marks = ", ".join("?" * len(self.cols))
        with self.con:
            self.con.execute(f"INSERT INTO runs VALUES ({marks})", values)
            self.con.execute(
                "INSERT INTO timing VALUES (?, ?, ?)",
                (timing["run"], timing["wall_s"], timing["worker"]),
            )

    def close(self) -> None:
        self.con.close()


def read_rows(path: Path, table: str = "runs") -> list[dict[str, Any]]:
    """Every row of a result table, by run index, as dicts."""
    con = sqlite3.connect(path)
    try:
        cur = con.execute(f"SELECT * FROM {table} ORDER BY run")
        names = [c[0] for c in cur.description]
        return [dict(zip(names, r, strict=True)) for r in cur.fetchall()]
    finally:
        con.close()


def read_meta(path: Path) -> dict[str, str]:
    """The ``campaign`` table of a result file."""
    con = sqlite3.connect(path)
    try:
        return dict(con.execute("SELECT key, value FROM campaign").fetchall())
    finally:
        con.close()
