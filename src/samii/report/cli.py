"""``samii report DIR [--out FILE] [--overwrite] [--screenshot PNG]``: write a main job's ``report.html``
again from its folder (the main job writes it itself), and optionally a screenshot of it in a headless
browser."""

from __future__ import annotations

import argparse
from pathlib import Path

from samii.cli_args import nonempty_path

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", metavar="DIR", type=nonempty_path, help="a main job's output folder (samii run --out DIR)")
    p.add_argument("--out", metavar="FILE", type=nonempty_path, help="where to write the page (default DIR/report.html)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the page (and --screenshot) if it exists; the main job's own DIR/report.html too")
    p.add_argument("--screenshot", metavar="PNG", type=nonempty_path,
                   help="also save a screenshot of the page in a headless Chromium (chromium from your system's packages; "
                        "SAMII_BROWSER names another)")
    p.add_argument("--width", type=int, default=1200, help="screenshot width in pixels (default 1200)")


def run(args: argparse.Namespace) -> int:
    from samii.errors import InputError
    from samii.outputs import check_output_file
    from samii.report.content import read_run_folder
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
    if args.screenshot:
        from samii.report.browser import find_browser

        check_output_file(Path(args.screenshot), overwrite=args.overwrite, option="--screenshot")
        if find_browser() is None:
            import os

            if os.environ.get("SAMII_BROWSER"):
                raise InputError(f"--screenshot: SAMII_BROWSER={os.environ['SAMII_BROWSER']} is no program (neither a file nor a "
                                 "command on PATH)")
            raise InputError("--screenshot: no Chromium found (install chromium, e.g. apt-get install chromium, or set SAMII_BROWSER)")
    run_folder = read_run_folder(folder)
    path = write_report(run_folder, out)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB, self-contained: open it in a browser)")
    if run_folder.gaps:
        import sys

        print(f"warning: {folder} lacks what a main job writes (the page marks it): {'; '.join(run_folder.gaps)}", file=sys.stderr)
    if args.screenshot:
        from samii.report.browser import screenshot

        shot = screenshot(path, Path(args.screenshot), width=args.width)
        print(f"wrote {shot.path} ({shot.width}x{shot.height} px, {shot.browser})")
    return 0
