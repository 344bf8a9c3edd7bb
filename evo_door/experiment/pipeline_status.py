"""Where a pipeline's results file stands, for ``show``, ``report``, the API and the
end of ``run`` (:func:`pipeline_summary`): its status and each stage's."""

from __future__ import annotations

from evo_door.files import FileLock


def pipeline_summary(path) -> dict | None:
    """Where a pipeline's file stands (None for a single run's file), JSON-able.

    ``path`` is a results file or a record :func:`~.reader.read_results` read (a command
    that goes on to show the stages reads the file once). ``status`` is complete,
    running (a process holds the file) or interrupted, as for a run; ``stages`` gives
    each declared stage's state (``complete``, ``running``, ``interrupted``, ``not
    started``) and its progress text.
    """
    from evo_door.experiment.reader import PipelineRecord, RunRecord, read_results
    from evo_door.experiment.results import run_status

    record = path if isinstance(path, (PipelineRecord, RunRecord)) else read_results(path)
    if not isinstance(record, PipelineRecord):
        return None
    path, attrs = record.path, record.attrs
    stages = []
    for name in record.stages:
        run = record.runs.get(name)
        shown = ("not started", "not started")
        if run is not None:
            status = run_status(path, run.attrs, run.config)
            shown = (status.state, status.text)
        sources = record.sources.get(name, {})
        uses = sorted(set(sources.values()))
        stages.append(
            {"name": name, "status": shown[0], "text": shown[1], "from": sources, "uses": uses}
        )
    state = attrs.get("status", "unknown")
    hint = ""
    if state != "complete":
        holder = FileLock.holder(path)
        if holder is not None:
            state = "running"
        else:
            state, hint = "interrupted", f"evo-door resume {path}"
    where = next((s for s in stages if s["status"] != "complete"), None)
    text = state
    if state != "complete" and where is not None:
        k = attrs["stages"].index(where["name"]) + 1
        text = f"{state} in stage {k}/{len(stages)} {where['name']} ({where['text']})"
    return {
        "file": str(path),
        "name": attrs.get("name", ""),
        "status": state,
        "status_text": text,
        "resume": hint,
        "stages": stages,
        "created": attrs.get("created", ""),
        "total_s": float(attrs.get("total_s", 0.0)),
    }
