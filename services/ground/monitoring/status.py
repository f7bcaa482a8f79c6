"""The monitor's live status on stderr: a rich table, one row per deputy, redrawn on a
terminal; otherwise one plain progress line every 10 % of the mission."""

from __future__ import annotations

import sys
from typing import Any

from services.ground.analysis.rundata import RunData


def _f(v: Any, fmt: str) -> str:
    """``v`` formatted by ``fmt``, or "-" when there is none."""
    return "-" if v is None else format(v, fmt)


RANK_LEGEND = (
    "s/i/rank: a learner's samples gathered / learning intervals closed / rank of its data : "
    "the rank it needs to learn"
)
COMPACT_ABOVE = 2  # deputies: with more, a plain progress line shows each one's error alone


def _learner(s: dict[str, Any]) -> bool:
    return "samples" in s and s.get("mode") != "lqr"


def _rank(s: dict[str, Any]) -> str:
    """A learner's progress, samples/intervals/rank:rank needed ("-" for LQR)."""
    if not _learner(s):
        return "-"
    return f"{s['samples']}/{s['intervals']}/{s['rank']}:{s['rank_needed']}"


class Status:
    """Terminal status: rich live table on a TTY, plain 10 % progress lines otherwise."""

    def __init__(self, data: RunData, tty: bool) -> None:
        self.data = data
        self.tty = tty
        self.next_pct = 10
        self.last_line = ""
        self._live: Any = None
        if tty:
            from rich.console import Console
            from rich.live import Live

            self._live = Live(
                console=Console(stderr=True), auto_refresh=False, redirect_stdout=False
            )
            self._live.start()

    def _table(self, counters: dict[str, int]) -> Any:
        from rich.table import Table

        d = self.data
        title = (
            f"ddvi {d.run}  t = {d.sim_t:.0f} s ({d.sim_t / d.period:.2f} / "
            f"{d.duration / d.period:.2f} orbits)  recorded {counters.get('recorded', 0)}  "
            f"rejected {counters.get('rejected', 0)}"
        )
        table = Table(title=title, title_justify="left", expand=False, caption=RANK_LEGEND)
        for col in ("deputy", "orbits", "y - y_ref [m]", "x [m]", "sigma3", "phase", "s/i/rank"):
            table.add_column(col, justify="left" if col in ("deputy", "phase") else "right")
        for dep in d.dep.deputy:
            s = d.live(dep)
            table.add_row(
                f"{dep.name} ({dep.controller})",
                f"{s['orbits']:.2f}",
                _f(s.get("ey"), "+.3f"),
                _f(s.get("x"), "+.3f"),
                _f(s.get("sigma3"), "+.4f"),
                str(s.get("phase", "-")),
                _rank(s),
            )
        return table

    def _line(self) -> str:
        """One plain progress line, each field named: with a few deputies, every deputy's
        along-track error, phase, x, sigma3 and a learner's data; with more, each one's error
        alone (and a learner's phase), so that the line stays short."""
        d = self.data
        head = (
            f"monitor: {100 * d.sim_t / d.duration:3.0f}% t={d.sim_t:.0f} s "
            f"({d.sim_t / d.period:.2f} of {d.duration / d.period:.2f} orbits)"
        )
        if len(d.dep.deputy) > COMPACT_ABOVE:
            parts = [f"{head} y-y_ref"]
            for dep in d.dep.deputy:
                s = d.live(dep)
                phase = f" {s.get('phase', '-')}" if _learner(s) else ""
                parts.append(f"{dep.name}: {_f(s.get('ey'), '+.1f')} m{phase}")
            return " | ".join(parts)
        parts = [head]
        for dep in d.dep.deputy:
            s = d.live(dep)
            ey, x, sigma3 = (
                _f(s.get("ey"), "+.1f"),
                _f(s.get("x"), "+.1f"),
                _f(s.get("sigma3"), "+.3f"),
            )
            part = f"{dep.name}: y-y_ref={ey} m {s.get('phase', '-')} x={x} m sigma3={sigma3}"
            if _learner(s):
                part += (
                    f" samples={s['samples']} intervals={s['intervals']} "
                    f"rank={s['rank']}/{s['rank_needed']}"
                )
            parts.append(part)
        return " | ".join(parts)

    def update(self, counters: dict[str, int]) -> None:
        if self._live is not None:
            self._live.update(self._table(counters), refresh=True)
            return
        d = self.data
        pct = 100 * d.sim_t / d.duration if d.duration > 0 else 0
        if pct >= self.next_pct:
            self.last_line = self._line()
            print(self.last_line, file=sys.stderr, flush=True)
            while self.next_pct <= pct:
                self.next_pct += 10

    def close(self, counters: dict[str, int]) -> None:
        if self._live is not None:
            self._live.update(self._table(counters), refresh=True)
            self._live.stop()
            self._live = None
        elif not self.tty and self._line() != self.last_line:
            print(self._line(), file=sys.stderr, flush=True)
