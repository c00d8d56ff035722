"""Running a campaign: resume from its folder, compute the rest where asked, then the table, summary and figures.

``run_campaign(campaign, out)`` is what ``rollbot-oc campaign`` does:

1. list the cases (their ids and seeds) and read the rows already in
   ``out/parts`` (``ResultStore``): those cases are not run again;
2. run the others (``execution.executor``: in this process, a local Dask
   cluster or an existing one), writing rows to part files as they finish,
   with a progress bar (tqdm, on stderr, silent when stderr is not a
   terminal unless ``progress=True``);
3. write ``results.parquet`` (one row per case, in case order), then
   ``summary.json``, ``summary.md`` and the kind's figures.

Interrupted (Ctrl-C, a crash), the rows of the finished cases stay in
``out/parts``; the same call again carries on from there.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from tqdm.auto import tqdm

from rollbot_oc.campaign.execution import check_workers, executor
from rollbot_oc.campaign.store import ResultStore
from rollbot_oc.campaign.summary import summarise, summary_markdown
from rollbot_oc.core.outputs import OutputFolder, atomic_write_text, write_json

__all__ = ["run_campaign", "CampaignResult"]


@dataclass
class CampaignResult:
    """A finished campaign.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per case (``results.parquet``).
    summary : dict
        ``summary.json``.
    folder : Path
        The output folder.
    paths : list of Path
        The files written (table, summaries, figures).
    """

    table: object
    summary: dict
    folder: Path
    paths: list = field(default_factory=list)


def run_campaign(campaign, out, workers: int | None = None, scheduler: str | None = None,
                 progress: bool | None = None, figures: bool = True) -> CampaignResult:
    """Run ``campaign`` into the folder ``out``, resuming what is there (see the module doc).

    Parameters
    ----------
    campaign : Campaign
    out : str, Path or OutputFolder
        The output folder (checked and created first).
    workers : int, optional
        Local worker processes; 1 runs in this process; default: this machine's cores.
    scheduler : str, optional
        Address of an existing Dask scheduler (default: ``$DASK_SCHEDULER_ADDRESS``, else a local cluster).
    progress : bool, optional
        Show a progress bar (None: only where stderr is a terminal).
    figures : bool
        Also write the figures.

    Raises
    ------
    ConfigError
        A bad folder, number of workers or scheduler, workers with other code, or another campaign running
        in the folder, all before any case runs.
    """
    workers, scheduler = check_workers(workers, scheduler)  # every user error before anything is written
    cases = campaign.cases()
    folder = out if isinstance(out, OutputFolder) else OutputFolder(out, "--out")
    start = time.perf_counter()
    startup, where, workers_used = 0.0, "nothing to run: every case had finished", 0
    with ResultStore(folder) as store:
        finished = store.finished()
        todo = [case for case in cases if case.id not in finished]
        if todo:
            with executor(campaign.kind, workers, scheduler) as place:
                startup, where, workers_used = time.perf_counter() - start, place.where, place.workers
                bar = tqdm(total=len(todo), desc=f"campaign {campaign.name}", unit="case", file=sys.stderr,
                           disable=None if progress is None else not progress)
                with bar:
                    for row in place.run(todo):
                        store.add(row)
                        bar.update()
        wall = time.perf_counter() - start
        store.flush()
        table = store.table(campaign.kind, cases)
        paths = [store.write_table(table)]
    summary = summarise(campaign, table, computed=len(todo), resumed=len(cases) - len(todo), wall_time=wall,
                        startup_time=startup, workers=workers_used, where=where)
    paths.append(write_json(folder / "summary.json", summary))
    paths.append(atomic_write_text(folder / "summary.md", summary_markdown(summary)))
    if figures:
        paths += campaign.kind.figures(table, folder)
    return CampaignResult(table, summary, folder.path, paths)
