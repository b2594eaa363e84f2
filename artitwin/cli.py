"""The ``artitwin`` command line: run scenes, make examples, inspect the store, open the UI."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from artitwin._cli_common import StoreOpt, _fail, _load_config, console
from artitwin._cli_queue import register as _register_queue_commands
from artitwin_core import ArtiTwinError
from schemas import PipelineConfig
from schemas._effects import EFFECT_SCOPES, MODELLED

app = typer.Typer(add_completion=False, no_args_is_help=True, help=__doc__)
store_app = typer.Typer(no_args_is_help=True, help="Inspect and maintain the artifact store.")
app.add_typer(store_app, name="store")
def _store_url(store: str | None) -> str:
    from flows._env import default_store_url

    return store or default_store_url()


def _print_summary(summary: dict[str, Any], out: Path | None) -> None:
    table = Table(title=f"scene {summary['scene']}")
    for col in ("stage", "status", "seconds", "key"):
        table.add_column(col)
    for name, s in summary["stages"].items():
        table.add_row(name, s["status"], f"{s.get('seconds', 0.0):.2f}", s.get("key", "")[:16])
    Console().print(table)
    for name, s in summary["stages"].items():
        for note in s.get("notes", []):
            console.print(f"[yellow]{name}:[/] {note}")
        if s.get("status") == "failed":
            console.print(f"[bold red]{name} failed:[/] {s['error']}")
    for j in summary.get("joints", []):
        console.print(f"joint {j['name']}: {j['type']}, axis {[round(v, 3) for v in j['axis']]}, "
                      f"pivot {[round(v, 3) for v in j['pivot']]} m, range {[round(v, 3) for v in j['range']]}")
    if summary.get("exports"):
        found = [(kind, summary["exports"].get(f"export/twin.{ext}")) for kind, ext in (("URDF", "urdf"), ("USD", "usda"))]
        named = ", ".join(f"{kind}: {path}" for kind, path in found if path)
        console.print(f"exports: {len(summary['exports'])} files under {out}" + (f" ({named})" if named else ""))
    if out is not None:
        console.print(f"summary: {out / 'summary.json'}")


def _run_scene(scene: Path, out: Path, config, store: str | None, use_prefect: bool) -> dict[str, Any]:
    if not scene.exists():
        _fail(f"scene folder {scene} does not exist")
    from flows._progress import terminal_sink

    # A progress bar on a terminal; one line per stage and periodic step counts otherwise (logs, CI).
    console.print(f"running stages on {scene} ...")
    with terminal_sink(sys.stderr):
        if use_prefect:
            from flows.scene import reconstruct_scene

            summary = reconstruct_scene(str(scene), config=config, store=_store_url(store), out=str(out))
        else:
            from flows.scene import run_scene_inline

            summary = run_scene_inline(scene, config, _store_url(store), out=out)
    return summary


def _run_and_report(scene: Path, out: Path, config, store: str | None, use_prefect: bool) -> None:
    """Run the scene and print its summary; a failed stage still prints (and wrote) the summary,
    then exits with status 1 naming the stage and its error."""
    from flows._pipeline import SceneFailed

    try:
        summary = _run_scene(scene, out, config, store, use_prefect)
    except SceneFailed as e:
        _print_summary(e.summary, out)
        _fail(f"{e}\nEverything that completed is in {out / 'summary.json'}"
              + (f"; the static recording's diagnosis: artitwin diagnose {out}" if "diagnose_static" in e.summary["stages"] else ""),
              code=1)
    except ArtiTwinError as e:
        _fail(str(e))
    _print_summary(summary, out)


_EFFECT_HELP = (
    "Model this physical effect (repeatable) in a scope, SCOPE:NAME: "
    + ", ".join(
        f"{'|'.join(EFFECT_SCOPES[e.name])}:{e.name}" + (f"={e.param.upper()}" if e.param else "")
        for e in MODELLED.values()
    )
    + " (joint: joint_0, joint_1, ...; a value is the one the diagnosis fitted). `artitwin diagnose` prints the "
    "ones a run needs, with their scope. A bare NAME goes where --diagnosis RUN found it (else: the static "
    "recording). Cached stages upstream of it are reused."
)


def _scope_effects(effects: list[str], diagnosis: Path | None, out: Path) -> list[str]:
    """``--effect`` entries with bare names placed where a diagnosis found them: the run
    ``diagnosis`` (an error if it has none), else the run already in ``out`` when there is one;
    a joint the diagnosis names (``joint_0``) becomes the name ``fit_joints`` fits that part under."""
    from flows._runs import (
        diagnosis_of,
        fit_joint_names,
        joint_effects_as_fitted,
        read_summary,
        scope_bare_effects,
    )

    source = diagnosis if diagnosis is not None else (out if (out / "summary.json").is_file() else None)
    report, names = None, {}
    if source is not None:
        try:
            where, summary = read_summary(source)
            report = diagnosis_of(summary, where)
            names = fit_joint_names(summary)
        except ArtiTwinError as e:
            if diagnosis is not None:
                _fail(f"--diagnosis: {e}")
        if report is None and diagnosis is not None:
            _fail(f"--diagnosis: {diagnosis} has no diagnosis; give a run that completed its diagnose stage.")
    scoped, notes = joint_effects_as_fitted(scope_bare_effects(effects, report), names)
    for line in notes:
        console.print(line)
    return scoped


@app.command()
def run(
    scene: Annotated[Path, typer.Argument(help="Scene folder holding the static and dynamic recordings.")],
    out: Annotated[Path, typer.Option("--out", help="Where summary.json and exports go.")] = Path("out"),
    config: Annotated[Path | None, typer.Option("--config", help="Pipeline config (JSON or YAML).")] = None,
    preset: Annotated[str, typer.Option("--preset", help="Config preset when no --config: default (sized for this machine: CPU or GPU), quick or full.")] = "default",
    store: StoreOpt = None,
    prefect: Annotated[bool, typer.Option("--prefect/--no-prefect", help="Run as a Prefect flow (default).")] = True,
    effect: Annotated[
        list[str] | None,
        typer.Option("--effect", help=_EFFECT_HELP),
    ] = None,
    diagnosis: Annotated[
        Path | None,
        typer.Option("--diagnosis", help="A run of this scene whose diagnosis places bare --effect names in the "
                     "scope it found them in (default: the run already in --out, if any)."),
    ] = None,
    sam2: Annotated[
        Path | None,
        typer.Option("--sam2", help="Local SAM2 checkpoint (.pt): propagate the part masks with SAM2's video "
                     "predictor (needs the sam2 package; nothing is downloaded)."),
    ] = None,
) -> None:
    """Run the whole pipeline on one scene."""
    cfg = _load_config(config, preset)
    if sam2 is not None:
        if not sam2.is_file():
            _fail(f"--sam2: {sam2} does not exist; give the path of a downloaded SAM2 checkpoint.")
        cfg = cfg.model_copy(update={"part_masks": cfg.part_masks.model_copy(update={"sam2_checkpoint": str(sam2.resolve())})})
    if effect:
        try:
            effect = _scope_effects(effect, diagnosis, out)
            cfg = cfg.with_effects(effect)
        except ValueError as e:
            _fail(f"--effect: {e}")
        console.print(f"modelling: {', '.join(cfg.enabled_effects())}")
    _run_and_report(scene, out, cfg, store, prefect)


@app.command()
def demo(
    out: Annotated[Path, typer.Option("--out", help="Where the example scene and the results go.")] = Path("out/demo"),
    store: StoreOpt = None,
    prefect: Annotated[bool, typer.Option("--prefect/--no-prefect")] = True,
) -> None:
    """Make the small built-in synthetic example scene and run the pipeline on it."""
    from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, write_scene

    scene_dir = out / "scene"
    if not (scene_dir / "scene.json").exists():
        with console.status("rendering the built-in example scene ..."):
            write_scene(generate_scene(BENCHMARK_SCENES["tiny"]), scene_dir)
    _run_and_report(scene_dir, out, PipelineConfig.preset("quick"), store, prefect)


@app.command()
def view(
    path: Annotated[Path, typer.Argument(help="Run folder (artitwin run --out DIR), its summary.json, a scene folder run into ./out, or a 3DGS .ply.")],
    port: Annotated[int, typer.Option("--port", help="Port on 127.0.0.1 (the next free one if it is taken).")] = 8080,
    joints: Annotated[Path | None, typer.Option("--joints", help="Joints JSON for a .ply (a summary.json works).")] = None,
    labels: Annotated[Path | None, typer.Option("--labels", help="Part labels .npy [N] for a .ply (0 background, 1 interior, 2+k part k).")] = None,
    residual: Annotated[Path | None, typer.Option("--residual", help="Residual .npy: [N] per Gaussian, or [M, 4] rows x, y, z, value.")] = None,
    export_dir: Annotated[Path | None, typer.Option("--export", help="Export folder whose collision meshes to show (default: the run's).")] = None,
) -> None:
    """Open the twin in the browser: a slider per joint, joint axes, capture cameras, residuals, collision meshes."""
    from artitwin._viewer import view as serve

    try:
        serve(path, port=port, joints=joints, labels=labels, residual=residual, export_dir=export_dir, echo=console.print)
    except ArtiTwinError as e:
        _fail(str(e))


@app.command()
def diagnose(
    run_dir: Annotated[Path, typer.Argument(help="Run folder (artitwin run --out DIR) or its summary.json.")],
    html_out: Annotated[Path | None, typer.Option("--html", help="Also write the diagnosis report here.")] = None,
    top: Annotated[int, typer.Option("--top", help="Show this many ranked effects.")] = 12,
) -> None:
    """Where the twin fails against the measurement, and which physical effect it is missing."""
    from flows._runs import diagnosis_of, not_modelled_advice, rank_findings, read_summary, rerun_effects

    try:
        where, summary = read_summary(run_dir)
        report = diagnosis_of(summary, where)
    except ArtiTwinError as e:
        _fail(str(e))
    if report is None:
        _fail(f"{where}: this run has no diagnose stage; rerun it with the full pipeline.")
    modelled = summary.get("effects") or []
    console.print(f"run {where}: the twin models {', '.join(modelled) or 'an ideal camera and ideal joints'}")
    table = Table(title="effects in every scope, ranked by the residual they explain")
    for col in ("#", "scope", "effect", "target", "explained", "significant", "enabled", "parameters"):
        table.add_column(col)
    for i, f in enumerate(rank_findings(report.findings)[:top]):
        params = ", ".join(f"{k}={v:.3g}" for k, v in f.params.items() if isinstance(v, int | float) and not isinstance(v, bool))
        table.add_row(str(i + 1), f.scope, f.name, f.target, f"{100 * f.explained_frac:.0f}%",
                      "yes" if f.significant else "no", "yes" if f.enabled else "", params[:60])
    Console().print(table)
    for line in report.conclusion:
        Console().print(f"- {line}")
    can, cannot = rerun_effects(report, modelled)
    scene = summary.get("scene", "SCENE")
    if can:
        flags = " ".join(f"--effect {e}" for e in sorted(set(can) | set(modelled)))
        Console().print(f"rerun with it modelled: artitwin run {scene} {flags} --out {where}-effects  "
                        f"(then: artitwin compare {where} {where}-effects)")
    if cannot:
        Console().print("diagnosed but not modelled by any stage in that scope:")
        for entry in cannot:
            Console().print(f"  - {not_modelled_advice(entry)}")
    if html_out is not None:
        html_out.parent.mkdir(parents=True, exist_ok=True)
        html_out.write_text(report.html, encoding="utf-8")
        console.print(f"report: {html_out}")
    else:
        for name in ("diagnosis.html", "diagnosis_dynamic.html"):
            if (where / name).is_file():
                console.print(f"report: {where / name}")


@app.command()
def compare(
    before: Annotated[Path, typer.Argument(help="The first run folder (A, 'before').")],
    after: Annotated[Path, typer.Argument(help="The second run folder of the same scene (B, 'after').")],
    html_out: Annotated[Path | None, typer.Option("--html", help="Where the comparison report goes (default: B/compare.html).")] = None,
) -> None:
    """Compare two runs of one scene: errors before and after, where they were concentrated, held-out frames."""
    from flows._runs import compare_run_folders

    target = html_out if html_out is not None else (after if after.is_dir() else after.parent) / "compare.html"
    try:
        cmp = compare_run_folders(before, after, target)
    except ArtiTwinError as e:
        _fail(str(e))
    for line in cmp.lead:
        Console().print(f"[bold]{line}[/]")
    for line in cmp.regressions:
        Console().print(f"[bold red]{line}[/]")
    table = Table(title=f"A = {cmp.a.name}  vs  B = {cmp.b.name}")
    for col in ("metric", "A", "B", "change", ""):
        table.add_column(col)
    for m in sorted(cmp.metrics, key=lambda m: -abs(m.relative) if m.relative == m.relative else 0)[:20]:
        pct = f"{100 * m.relative:+.0f}%" if m.relative == m.relative else "n/a"
        table.add_row(m.name, f"{m.a:.4g}", f"{m.b:.4g}", pct, "better" if m.improved else ("worse" if m.a != m.b else ""))
    Console().print(table)
    for line in cmp.conclusion:
        Console().print(f"- {line}")
    console.print(f"report: {target}")


@app.command()
def synth(
    name: Annotated[str, typer.Argument(help="Benchmark scene name, or 'random' (see --list).")] = "tiny",
    out: Annotated[Path, typer.Option("--out", help="Scene folder to write.")] = Path("scenes/tiny"),
    fmt: Annotated[str, typer.Option("--format", help="r3d, nerfstudio, record3d-exr or stray.")] = "r3d",
    seed: Annotated[int | None, typer.Option("--seed", help="Override the scene's seed (random: which draw, default 0).")] = None,
    list_: Annotated[bool, typer.Option("--list", help="List the named scenes and exit.")] = False,
) -> None:
    """Render a synthetic articulated scene with exact ground truth."""
    import dataclasses

    from artitwin_core.synth import BENCHMARK_SCENES, generate_scene, random_scene_spec, write_scene

    if list_:
        for key, spec in BENCHMARK_SCENES.items():
            typer.echo(f"{key}: {spec.furniture}, {spec.texture}")
        typer.echo("random: a scene drawn from the whole family (furniture, hand, handle, camera paths, "
                   "overlap, pose lag, exposure ...); --seed N picks the draw")
        return
    if name == "random":
        spec = random_scene_spec(0 if seed is None else seed)
    elif name not in BENCHMARK_SCENES:
        _fail(f"unknown scene {name!r}; known: {', '.join(BENCHMARK_SCENES)}, random")
    else:
        spec = BENCHMARK_SCENES[name]
        if seed is not None:
            spec = dataclasses.replace(spec, seed=seed)
    with console.status(f"rendering {name} ..."):
        write_scene(generate_scene(spec), out, fmt=fmt)
    typer.echo(str(out))


@app.command()
def ui(
    port: Annotated[int, typer.Option(help="Port on 127.0.0.1.")] = 4200,
) -> None:
    """Start the Prefect UI on 127.0.0.1 over this project's local run history."""
    from flows._env import apply_prefect_defaults

    apply_prefect_defaults()
    console.print(f"Prefect UI at http://127.0.0.1:{port} (PREFECT_HOME={os.environ['PREFECT_HOME']}); Ctrl-C stops it.")
    cmd = [sys.executable, "-m", "prefect", "server", "start", "--host", "127.0.0.1", "--port", str(port)]
    raise typer.Exit(subprocess.call(cmd))


@store_app.command("ls")
def store_ls(store: StoreOpt = None) -> None:
    """List stored artifacts, oldest first."""
    from infra.store import ArtifactStore

    st = ArtifactStore(_store_url(store))
    table = Table(title=st.url)
    for col in ("key", "kind", "stage", "label", "size", "created"):
        table.add_column(col)
    for info in st.ls():
        table.add_row(
            info.key[:16],
            info.kind,
            str(info.record.get("stage", "")),
            str(info.record.get("label", "")),
            f"{info.size_bytes / 1e6:.2f} MB",
            time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(info.created)),
        )
    Console().print(table)


@store_app.command("show")
def store_show(key: Annotated[str, typer.Argument(help="Full key or a unique prefix.")], store: StoreOpt = None) -> None:
    """Show what an artifact was computed from and what it holds."""
    from infra.store import ArtifactStore, StoreError

    st = ArtifactStore(_store_url(store))
    matches = [k for k in st.keys() if k.startswith(key)]
    if len(matches) != 1:
        _fail(f"{len(matches)} artifacts match {key!r}; give more of the key")
    try:
        info = st.info(matches[0])
        art = st.get(matches[0])
    except StoreError as e:
        _fail(str(e))
    fields = {}
    for name in type(art).model_fields:
        v = getattr(art, name)
        fields[name] = f"array {v.dtype}{list(v.shape)}" if hasattr(v, "shape") else v
    typer.echo(
        json.dumps(
            {"key": info.key, "kind": info.kind, "object": info.object_path, "bytes": info.size_bytes, "record": info.record, "fields": fields},
            indent=2,
            default=str,
        )
    )


@store_app.command("verify")
def store_verify(
    store: StoreOpt = None,
    repair: Annotated[bool, typer.Option("--repair", help="Set corrupt artifacts aside so reruns recompute them.")] = False,
) -> None:
    """Check every artifact's files against its manifest (SHA-256)."""
    from infra.store import ArtifactStore

    st = ArtifactStore(_store_url(store))
    problems = st.verify(repair=repair)
    for p in problems:
        console.print(f"[red]{p.key[:16]}[/] {p.what}")
    if problems:
        console.print(f"{len({p.key for p in problems})} corrupt artifact(s){' set aside' if repair else '; rerun with --repair'}")
        raise typer.Exit(1)
    typer.echo("all artifacts intact")


@store_app.command("gc")
def store_gc(
    store: StoreOpt = None,
    grace: Annotated[float, typer.Option(help="Keep unreferenced files younger than this (seconds).")] = 3600.0,
    dry_run: Annotated[bool, typer.Option("--dry-run")] = False,
) -> None:
    """Remove leftovers of killed or racing writers and finished leases."""
    from infra.store import ArtifactStore

    removed = ArtifactStore(_store_url(store)).gc(grace_s=grace, dry_run=dry_run)
    for rel in removed:
        typer.echo(("would remove " if dry_run else "removed ") + rel)
    typer.echo(f"{len(removed)} item(s)")


def main() -> None:
    try:
        app()
    except ArtiTwinError as e:  # raised outside a command's own handling
        console.print(f"[bold red]error:[/] {e}")
        sys.exit(2)


_register_queue_commands(app)
