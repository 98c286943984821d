"""``hystfit batch``: run the jobs of a TOML batch file, one summary table, per-job exit codes."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Annotated

import typer

from ..errors import Terminated
from .app import LAST_ERROR, app, click_exceptions, command, error_line, stop_code
from .common import (ExecutorOpt, JsonOut, Quiet, Resume, Scheduler, jobs_option, new_table, print_json, stderr,
                     stdout)

BatchJobs = jobs_option("Parallel processes of every job that has none of its own (the numbers do not depend on it).")

#: exit code → what it means for a job (see docs/scale.md)
JOB_STATUS = {0: "ok", 2: "bad input", 3: "no result", 4: "some cells failed", 130: "interrupted",
              143: "terminated"}


def _argv(job, command, path: Path) -> list[str]:
    """The command line of ``job``; an option the command does not have is a ConfigError naming the job."""
    from ..errors import ConfigError

    flags = {}
    for p in command.params:
        if p.param_type_name == "option":
            for o in p.opts:
                flags[o] = (p, False)
            for o in p.secondary_opts:
                flags[o] = (p, True)
    args = [job.command] + ([str(job.params)] if job.params is not None else []) + [str(d) for d in job.data]
    args += ["--out", str(job.out)]
    for key, value in job.options.items():
        flag = f"--{key.replace('_', '-')}"
        if flag not in flags or flags[flag][1]:
            known = sorted(o[2:] for o, (p, second) in flags.items() if not second and o.startswith("--")
                           and o not in ("--out", "--help") and o[2:] not in BATCH_OWNED)
            raise ConfigError(f"{path}: job {job.name!r}: {job.command} has no option {key!r}; one of: "
                              f"{', '.join(known)}")
        p = flags[flag][0]
        if key in BATCH_OWNED:
            raise ConfigError(f"{path}: job {job.name!r}: {key} is the batch's own option ({BATCH_OWNED[key]}); "
                              "remove it from the job or from [defaults]")
        if p.is_flag and not isinstance(value, bool):
            # a text on an on/off option became a second argument: an extra data file (a blind test's
            # plots = "D/a60V_f80Hz.csv" added a condition to the job's table and exited 0)
            raise ConfigError(f"{path}: job {job.name!r}: option {key!r} is on/off; write {key} = true or "
                              f"{key} = false, not {value!r}")
        if value is False and p.is_flag and p.secondary_opts:
            args.append(max(p.secondary_opts, key=len))
        elif isinstance(value, bool) and p.is_flag:
            if value:
                args.append(flag)
        elif isinstance(value, list):
            for v in value:
                args += [flag, str(v)]
        else:
            args += [flag, str(value).lower() if isinstance(value, bool) else str(value)]
    return args


#: options a job cannot set, and why: the batch sets them for every job
BATCH_OWNED = {"json": "hystfit batch --json prints every job's row as one JSON document; a job's own would "
                       "print a second one beside it"}


def _checked(command, argv: list[str], path: Path, name: str) -> None:
    """Parse ``argv`` (a job's command line) as its command would, without running it: a value the
    option does not take (``seed = -5``, ``runs = 2.7``, ``jobs = true``) is a ConfigError naming the
    batch file, the job and the option before any job runs."""
    from ..errors import ConfigError

    try:
        command.make_context(argv[0], list(argv[1:]), resilient_parsing=False)
    except click_exceptions.ClickException as exc:
        raise ConfigError(f"{path}: job {name!r}: {exc.format_message().rstrip('.')}; fix the job's option "
                          f"(see 'hystfit {argv[0]} --help')") from None


def _run(root, argv: list[str]) -> int:
    """Run one job in this process; its exit code (its own error line is already printed)."""
    try:
        rv = root.main(args=argv, prog_name="hystfit", standalone_mode=False)
        return rv if isinstance(rv, int) else 0
    except click_exceptions.ClickException as exc:
        error_line(f"{exc.format_message()} (see 'hystfit {argv[0]} --help')")
        return exc.exit_code
    except typer.Abort as exc:  # Ctrl-C or SIGTERM while the job's command line was parsed
        # (typer's own Abort: recent typer vendors click, whose exceptions module has none — the
        # clause raised AttributeError on every exception it was asked about, a blind test's find)
        return stop_code(exc.__context__) if isinstance(exc.__context__, KeyboardInterrupt) else 130
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 1
    except Exception as exc:  # a defect of one job: said in one line, the batch goes on with the next
        error_line(f"job {argv[0]}: internal error {type(exc).__name__}: {exc} (please report it)")
        return 1


@command()
def batch(
    jobs_file: Annotated[Path, typer.Argument(help="TOML batch file: a defaults table and job tables "
                                                   "(see docs/scale.md).", show_default=False)],
    resume: Resume = False,
    jobs: BatchJobs = None,
    executor: ExecutorOpt = "local",
    scheduler: Scheduler = None,
    json_out: JsonOut = False,
    quiet: Quiet = False,
) -> None:
    """Run the jobs of JOBS_FILE (identify, compare, diagnose, simulate) one after the other.

    A job that fails does not stop the others; the table gives each job's exit code. With --resume
    a job whose output directory is already written is skipped and the others continue from the
    cells they stored. Exit code 0 when every job succeeded, 3 when every job failed, 4 when some
    did, 130 on Ctrl-C, 143 on SIGTERM (no further job is started).
    """
    from typer.main import get_command

    from ..batch import load_batch
    from ..errors import CellsFailedError, NoResultError

    batch_jobs = load_batch(jobs_file)
    root = get_command(app)
    runs = []
    for job in batch_jobs:  # every job's options are checked before any job runs: a typo is exit 2 at once
        command = root.commands[job.command]
        have = {o for p in command.params for o in p.opts}
        opts = {k: v for k, v in job.defaults.items() if f"--{k.replace('_', '-')}" in have}
        opts.update(job.options)
        for key, value in (("jobs", jobs), ("executor", executor if executor != "local" else None),
                           ("scheduler", scheduler)):
            if value is not None and f"--{key}" in have and key not in opts:
                opts[key] = value
        if resume and "--resume" in have:
            opts["resume"] = True
        if json_out and "--quiet" in have:
            opts["quiet"] = True  # the batch's JSON is stdout's only document (a job's quiet = false printed its table)
        elif quiet and "--quiet" in have:
            opts.setdefault("quiet", True)
        argv = _argv(replace(job, options=opts), command, jobs_file)
        _checked(command, argv, jobs_file, job.name)
        runs.append((job, argv))
    rows = []  # (job, exit code, status, seconds, its error line)
    interrupted: KeyboardInterrupt | None = None
    for job, argv in runs:
        t0 = time.perf_counter()
        if resume and job.out.is_dir() and any(job.out.iterdir()):
            rows.append((job, 0, "done before (skipped)", 0.0, None))
            continue
        if not quiet and not json_out:
            stderr.print(f"== batch: {job.name}: hystfit {' '.join(argv)}", markup=False, highlight=False,
                         soft_wrap=True)
        LAST_ERROR.clear()
        code = _run(root, argv)
        rows.append((job, code, JOB_STATUS.get(code, "error"), time.perf_counter() - t0,
                     LAST_ERROR[0] if code != 0 and LAST_ERROR else None))
        if code in (130, Terminated.exit_code):  # Ctrl-C or SIGTERM: the batch stops too
            interrupted = Terminated() if code == Terminated.exit_code else KeyboardInterrupt()
            break
    ran = len(rows)
    # the jobs a Ctrl-C or SIGTERM left unstarted are listed too (a blind test's script saw them vanish)
    rows += [(job, None, "not started", 0.0, None) for job, _ in runs[ran:]]
    if json_out:
        print_json({"jobs": [{"name": j.name, "command": j.command, "out": str(j.out), "exit_code": c, "status": s,
                              "wall_time_s": t, "error": e} for j, c, s, t, e in rows]})
    elif not quiet:
        table = new_table(title=f"batch {jobs_file}: {ran} of {len(runs)} job(s) run")
        for col in ("job", "command", "exit", "status", "time s", "out"):
            table.add_column(col, justify="right" if col in ("exit", "time s") else "left")
        for j, c, s, t, _ in rows:
            table.add_row(j.name, j.command, "–" if c is None else str(c), s, f"{t:.1f}", str(j.out))
        stdout.print(table)
    rows = rows[:ran]
    failed = [r for r in rows if r[1] != 0]
    if interrupted:  # the job said so in its own error line: the batch stops with its code, not a second line
        raise typer.Exit(stop_code(interrupted))
    if failed and len(failed) == len(rows):
        raise NoResultError(f"every job of {jobs_file} failed (exit codes {', '.join(str(r[1]) for r in failed)})")
    if failed:
        raise CellsFailedError(f"{len(failed)} of {len(rows)} job(s) of {jobs_file} failed: "
                               + ", ".join(f"{j.name} (exit {c})" for j, c, _, _, _ in failed))
