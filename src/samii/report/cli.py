"""``samii report DIR [--out FILE] [--overwrite] [--screenshot PNG]``: write a main job's ``report.html``
again from its folder (the main job writes it itself), and optionally a screenshot of it in a headless
browser."""

from __future__ import annotations

import argparse
from pathlib import Path

from samii.cli_args import add_out, add_overwrite, nonempty_path

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", metavar="DIR", type=nonempty_path, help="a main job's output folder (samii run --out DIR)")
    add_out(p, "where to write the page (default DIR/report.html)", metavar="FILE")
    add_overwrite(p, "replace the page (and --screenshot) if it exists; the main job's own DIR/report.html too")
    p.add_argument(
        "--screenshot",
        metavar="PNG",
        type=nonempty_path,
        help="also save a screenshot of the page in a headless Chromium (chromium from your system's packages; SAMII_BROWSER names another)",
    )
    p.add_argument("--width", type=int, default=1200, help="screenshot width in pixels (default 1200)")


def run(args: argparse.Namespace) -> int:
    from samii.errors import InputError
    from samii.outputs import check_output_file
    from samii.pipeline import Run
    from samii.report.content import gaps
    from samii.report.page import REPORT_NAME, write_report

    if args.screenshot and not str(args.screenshot).lower().endswith(".png"):
        raise InputError(f"--screenshot {args.screenshot}: expected a .png file")
    if not 320 <= args.width <= 4000:
        raise InputError(f"--width {args.width}: expected 320...4000 pixels")
    folder = Path(args.folder)
    out = Path(args.out) if args.out else folder / REPORT_NAME
    if args.out:
        check_output_file(out, overwrite=args.overwrite, option="--out")
    elif out.is_dir():
        raise InputError(f"{out}: is a folder; the report is a file (remove the folder, or write the page elsewhere with --out FILE)")
    elif out.exists() and not args.overwrite:  # as every command's --out: nothing replaced unless asked
        raise InputError(f"{out}: exists (the main job wrote it); pass --overwrite to write it again, or --out FILE to write it elsewhere")
    _not_the_runs_own(folder, out, option="--out", allowed=lambda rel: rel.suffix.lower() in (".html", ".htm"), instead=" (or as DIR/report.html)")
    if args.screenshot:
        from samii.report.browser import find_browser
        from samii.report.content import STAGE_FIGURES

        _not_the_runs_own(folder, Path(args.screenshot), option="--screenshot", allowed=lambda rel: str(rel) not in STAGE_FIGURES.values())

        check_output_file(Path(args.screenshot), overwrite=args.overwrite, option="--screenshot")
        if find_browser() is None:
            import os

            if os.environ.get("SAMII_BROWSER"):
                raise InputError(f"--screenshot: SAMII_BROWSER={os.environ['SAMII_BROWSER']} is no program (neither a file nor a command on PATH)")
            raise InputError("--screenshot: no Chromium found (install chromium, e.g. apt-get install chromium, or set SAMII_BROWSER)")
    run = Run.load(folder)
    if args.screenshot:
        path, shot = _page_and_screenshot(run, out, Path(args.screenshot), args.width)
    else:
        path, shot = write_report(run, out), None
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB, self-contained: open it in a browser)")
    if lacks := gaps(run):
        import sys

        print(f"warning: {folder} lacks what a main job writes (the page marks it): {'; '.join(lacks)}", file=sys.stderr)
    if shot is not None:
        print(f"wrote {shot.path} ({shot.width}x{shot.height} px, {shot.browser})")
    return 0


def _not_the_runs_own(folder: Path, path: Path, *, option: str, allowed, instead: str = "") -> None:
    """Refuse an output that would replace a file the page is made from (``--out DIR/summary.json --overwrite`` wrote
    the page over the run's summary, and the folder could not be reported again)."""
    from samii.errors import InputError

    try:
        rel = path.resolve().relative_to(folder.resolve())
    except (ValueError, OSError):
        return
    if not allowed(rel):
        raise InputError(
            f"{option} {path}: lies in the run's folder {folder} and would replace one of the files the page is made "
            f"from; write it elsewhere{instead}"
        )


def _page_and_screenshot(run, out: Path, png: Path, width: int):
    """The page and its screenshot, both or neither: the page is written and shot under hidden names beside their places,
    then both renamed into place (a browser that failed left the new page without its screenshot, and exit 1)."""
    import dataclasses
    import os

    from samii.errors import InputError, uninterrupted
    from samii.outputs import parent_made_for
    from samii.report.browser import screenshot
    from samii.report.page import write_report

    tmp_page = out.parent / f".{out.stem}.samii-{os.getpid()}.html"  # (the browser reads it as HTML by its suffix)
    tmp_png = png.parent / f".{png.stem}.samii-{os.getpid()}.png"
    with parent_made_for(out), parent_made_for(png):  # (a folder made for them removed again on failure: after the finally)
        try:
            write_report(run, tmp_page)
            try:
                shot = screenshot(tmp_page, tmp_png, width=width)
            except RuntimeError as exc:  # the browser's failure, not the run's: said as such, nothing kept
                raise InputError(f"--screenshot: {str(exc).replace(str(tmp_page.absolute()), str(out))}; nothing was written") from None
            with uninterrupted(done=out):
                os.replace(tmp_page, out)
                os.replace(tmp_png, png)
        finally:
            for t in (tmp_page, tmp_png):
                t.unlink(missing_ok=True)
    return out, dataclasses.replace(shot, path=png)
