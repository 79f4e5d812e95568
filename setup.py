"""Build of samii's native part: the hydraulic actuator plugin, and the embedded default model.

Everything else about the package is declared in pyproject.toml. This file only adds two build
steps, both run by ``pip install .`` and ``pip install -e .``:

1. ``src/samii/sim/hydraulic.c`` is compiled into ``samii/sim/libsamii_hydraulic.so``, a plain
   shared library (a MuJoCo plugin, not a Python extension module) linked against the
   ``libmujoco.so.<version>`` shipped in the ``mujoco-core`` wheel that ``[build-system]`` pins.
   Its run path points at the ``mujoco`` package next to ``samii`` in site-packages. The MuJoCo
   version it was compiled against is written to ``samii/sim/_plugin_build.json``;
   ``samii.sim.plugin`` refuses to load the library under any other version.
2. For a regular (non-editable) install, the top-level ``models/samii/`` folder is copied into the
   package as ``samii/_model/`` so the installed package carries its default model. An editable
   install reads ``models/samii/`` from the checkout instead (no stale copy).
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import os
import re
import shutil
import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
PLUGIN_EXT = "samii.sim.libsamii_hydraulic"
PLUGIN_SOURCE = "src/samii/sim/hydraulic.c"
BUILD_INFO = "_plugin_build.json"
MODEL_SOURCE = ROOT / "models" / "samii"
MODEL_PACKAGE_DIR = ("samii", "_model")


def _mujoco_core() -> tuple[Path, str]:
    """Folder of the ``mujoco`` package providing headers and library, and its version."""
    spec = importlib.util.find_spec("mujoco")
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError(
            "building samii needs the mujoco-core wheel (headers and libmujoco) in the build "
            "environment; it is listed in [build-system] requires of pyproject.toml"
        )
    folder = Path(next(iter(spec.submodule_search_locations)))
    version = importlib.metadata.version("mujoco-core")
    return folder, version


def _header_version(include_dir: Path) -> int:
    text = (include_dir / "mujoco" / "mujoco.h").read_text()
    match = re.search(r"#define\s+mjVERSION_HEADER\s+(\d+)", text)
    if not match:
        raise RuntimeError(f"mjVERSION_HEADER not found in {include_dir / 'mujoco' / 'mujoco.h'}")
    return int(match.group(1))


class BuildPlugin(build_ext):
    """Compile the MuJoCo plugin as a plain shared library against the mujoco-core wheel."""

    def finalize_options(self) -> None:
        super().finalize_options()
        if getattr(self, "_mujoco", None):
            return  # finalize_options can run more than once
        # always recompile (under a second): a build/ folder left from another MuJoCo version
        # must not be reused, and file dates cannot tell
        self.force = True
        folder, version = _mujoco_core()
        include = folder / "include"
        if sys.platform.startswith("linux"):
            library = folder / f"libmujoco.so.{version}"
            rpath = "-Wl,-rpath,$ORIGIN/../../mujoco"  # site-packages/samii/sim -> site-packages/mujoco
        elif sys.platform == "darwin":
            library = folder / f"libmujoco.{version}.dylib"
            rpath = "-Wl,-rpath,@loader_path/../../mujoco"
        else:
            raise RuntimeError(f"the samii hydraulic plugin is built on Linux and macOS, not {sys.platform}")
        if not library.exists() or not (include / "mujoco" / "mjplugin.h").exists():
            raise RuntimeError(f"mujoco-core {version} at {folder} lacks {library.name} or include/mujoco")
        self._mujoco = {"folder": folder, "version": version, "header": _header_version(include)}
        for ext in self.extensions:
            if ext.name == PLUGIN_EXT:
                ext.include_dirs.append(str(include))
                ext.extra_objects.append(str(library))  # DT_NEEDED becomes its soname
                ext.extra_link_args.append(rpath)

    def get_ext_filename(self, fullname: str) -> str:
        # a plugin library, not a CPython module: no ABI suffix. distutils asks both with the full
        # dotted name and with its last component.
        if fullname in (PLUGIN_EXT, PLUGIN_EXT.rpartition(".")[2]):
            suffix = ".dylib" if sys.platform == "darwin" else ".so"
            return str(Path(*fullname.split("."))) + suffix
        return super().get_ext_filename(fullname)

    def get_export_symbols(self, ext: Extension) -> list[str]:
        if ext.name == PLUGIN_EXT:
            return []  # no PyInit_* function: registration runs from a library constructor
        return super().get_export_symbols(ext)

    def _info_path(self, ext_path: str) -> Path:
        return Path(ext_path).with_name(BUILD_INFO)

    def build_extension(self, ext: Extension) -> None:
        if ext.name != PLUGIN_EXT:
            return super().build_extension(ext)
        # drop run paths the Python build put into the link command (e.g. its own lib folder):
        # the plugin's only run path is the mujoco package's
        linker = list(self.compiler.linker_so)
        self.compiler.linker_so = [arg for arg in linker if not arg.startswith("-Wl,-rpath,")]
        try:
            super().build_extension(ext)
        finally:
            self.compiler.linker_so = linker
        if ext.name == PLUGIN_EXT:
            library = Path(self.get_ext_fullpath(ext.name))
            info = {
                "library": library.name,
                "mujoco_version": self._mujoco["version"],
                "mjVERSION_HEADER": self._mujoco["header"],
                "source": PLUGIN_SOURCE,
            }
            self._info_path(str(library)).write_text(json.dumps(info, indent=2) + "\n")

    def copy_extensions_to_source(self) -> None:
        # editable install: put the library and its build record into src/samii/sim/. Replace
        # atomically (copy, then rename): processes that have the old library mapped keep a valid
        # file instead of one truncated under them.
        build_py_cmd = self.get_finalized_command("build_py")
        for ext in self.extensions:
            inplace, regular = self._get_inplace_equivalent(build_py_cmd, ext)
            pairs = [(regular, inplace)]
            if ext.name == PLUGIN_EXT:
                pairs.append((str(self._info_path(regular)), str(self._info_path(inplace))))
            for source, target in pairs:
                partial = target + ".partial"
                shutil.copyfile(source, partial)
                shutil.copymode(source, partial)
                os.replace(partial, target)

    def get_outputs(self) -> list[str]:
        outputs = super().get_outputs()
        return outputs + [str(self._info_path(p)) for p in outputs if Path(p).stem == "libsamii_hydraulic"]

    def get_output_mapping(self) -> dict[str, str]:
        mapping = super().get_output_mapping()
        extra = {str(self._info_path(k)): str(self._info_path(v)) for k, v in mapping.items() if Path(k).stem == "libsamii_hydraulic"}
        return {**mapping, **extra}


class BuildPyWithModel(build_py):
    """Copy models/samii/ into the package as samii/_model/ (regular installs only)."""

    def run(self) -> None:
        super().run()
        if self.editable_mode:
            return  # an editable install reads models/samii/ from the checkout
        if not MODEL_SOURCE.is_dir():
            raise RuntimeError(f"default model folder {MODEL_SOURCE} is missing")
        target = Path(self.build_lib, *MODEL_PACKAGE_DIR)
        if target.exists():
            shutil.rmtree(target)
        shutil.copytree(MODEL_SOURCE, target)


setup(
    ext_modules=[
        Extension(
            PLUGIN_EXT,
            sources=[PLUGIN_SOURCE],
            extra_compile_args=["-O2", "-std=c11", "-Wall", "-Wextra", "-Wno-unused-parameter"],
        )
    ],
    cmdclass={"build_ext": BuildPlugin, "build_py": BuildPyWithModel},
)
