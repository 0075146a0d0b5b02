"""Compiles the board's translation units as PlatformIO would for env nano33ble (and nano33ble_m2cgen), against
an ArduinoCore-mbed checkout and ArduinoBLE, without PlatformIO. It compiles; it does not link (libmbed.a is a
prebuilt archive that is not needed to judge our code: its ABI is checked against the variant's other
prebuilt archives instead).

The flags, in the order PlatformIO's builder applies them (platformio-core piobuild.ProcessProgramDeps, then
builder-framework-arduino-core-mbed/arduino-core-mbed.py, then the library builders):
  1. board extra_flags (-DARDUINO_ARDUINO_NANO33BLE -DARDUINO_ARCH_NRF52840), then platformio.ini build_flags
     (-D -> CPPDEFINES, -I -> CPPPATH, -std=c++/gnu++ -> CXXFLAGS, -std=c/gnu -> CFLAGS, the rest -> CCFLAGS);
  2. the variant: CCFLAGS += sorted(cflags & cxxflags), CFLAGS += sorted(cflags - cxxflags), CXXFLAGS +=
     sorted(cxxflags - cflags), CPPDEFINES += defines.txt, then -iprefix<core> @includes.txt -nostdlib,
     ARDUINO=10810 ARDUINO_ARCH_MBED, the core's include dirs, then the builder's FPU flags
     (-mfloat-abi=soft -mfpu=fpv4-sp-d16, appended last);
  3. platformio.ini build_unflags removed from every list;
  4. per library: library.json build.flags appended to its own copy, its build.unflags removed.
A C++ unit is compiled as `g++ -c CXXFLAGS CCFLAGS -D... -I... file` (SCons CXXCOM), a C unit as
`gcc -c CFLAGS CCFLAGS -D... -I... file`.

Checks (exit 1 on any): a compiler error or warning in our units (main.cpp, firmware/lib, the models); a
soft-float or double helper (__aeabi_f*, __aeabi_d*, __aeabi_[u]l2f/d) referenced by them; a float ABI that
does not match the variant's prebuilt archives (they use the base calling convention with FPv4 code:
-mfloat-abi=softfp; -mfloat-abi=hard objects would not link with them); no FPU instruction where floats are;
the default env's (platformio.ini default_envs: the node tables the repository ships) code + models over the
256 KB flash budget. The m2cgen env is the comparison form of the same export: its flash is printed beside the
default's, not gated (m2cgen's code takes ~2x the node tables' bytes).
Framework units (core, variant, ArduinoBLE) are compiled with the same environment: errors fail, their
warnings are counted only (not our code).

    python3 scripts/board_build.py --core DIR --ble DIR [--out DIR] [--env nano33ble] [--no-framework]
"""

from __future__ import annotations

import argparse
import configparser
import json
import re
import shlex
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VARIANT = "ARDUINO_NANO33BLE"
BOARD_EXTRA_FLAGS = "-DARDUINO_ARDUINO_NANO33BLE -DARDUINO_ARCH_NRF52840"  # boards/nano33ble.json
PLATFORMIO_MACRO = "PLATFORMIO=60118"
BUILDER_FPU = ["-mfloat-abi=soft", "-mfpu=fpv4-sp-d16"]  # arduino-core-mbed.py configure_fpu_flags
SOFT_HELPER = re.compile(r"\b__aeabi_[fd]\w+\b")  # float/double arithmetic and conversions in software
INT64_TO_FLOAT = re.compile(r"\b__aeabi_u?l2f\b")   # impactcore.h int64_to_float's > 32-bit fallback (noted)
FLASH_BUDGET = 256 * 1024


class Env:
    """The flag lists of one SCons environment."""

    def __init__(self):
        self.ccflags: list[str] = []
        self.cflags: list[str] = []
        self.cxxflags: list[str] = []
        self.defines: list[str] = []
        self.cpppath: list[str] = []

    def copy(self) -> "Env":
        e = Env()
        for k, v in vars(self).items():
            setattr(e, k, list(v))
        return e

    def process_flags(self, flags: list[str], base: Path) -> None:
        """platformio's ParseFlagsExtended + Append, for the flag kinds this project uses."""
        it = iter(flags)
        for f in it:
            if f in ("-D", "-I"):
                f += next(it)
            if f.startswith("-D"):
                self.defines.append(f[2:])
            elif f.startswith("-I"):
                p = Path(f[2:])
                self.cpppath.append(str(p if p.is_absolute() else (base / p).resolve()))
            elif f.startswith(("-std=c++", "-std=gnu++")):
                self.cxxflags.append(f)
            elif f.startswith(("-std=c", "-std=gnu")):
                self.cflags.append(f)
            else:
                self.ccflags.append(f)

    def process_unflags(self, unflags: list[str]) -> None:
        for u in unflags:
            for lst in (self.ccflags, self.cflags, self.cxxflags):
                while u in lst:
                    lst.remove(u)
            if u.startswith("-D"):
                self.defines = [d for d in self.defines if d != u[2:] and d.split("=")[0] != u[2:]]

    def command(self, src: Path, obj: Path) -> list[str]:
        c = src.suffix == ".c"
        tool = "arm-none-eabi-gcc" if c else "arm-none-eabi-g++"
        lang = self.cflags if c else self.cxxflags
        return ([tool, "-o", str(obj), "-c", *lang, *self.ccflags, *("-D" + d for d in self.defines),
                 *("-I" + p for p in self.cpppath), str(src)])


def read_lines(path: Path) -> list[str]:
    return [ln.strip() for ln in path.read_text().splitlines() if ln.strip()]


def ini_env(name: str) -> dict:
    cp = configparser.ConfigParser(interpolation=None, inline_comment_prefixes=(";",))
    cp.read(ROOT / "platformio.ini")
    sec = dict(cp[f"env:{name}"])
    base = sec.get("extends")
    if base:
        merged = dict(cp[base.strip()])
        merged.update(sec)
        sec = merged

    def ref(m):  # ${section.option} (PlatformIO's interpolation; options hold no dots here)
        section, option = m.group(1).rsplit(".", 1)
        return cp[section][option]
    return {k: re.sub(r"\$\{([^}]+)\}", ref, v) for k, v in sec.items()}


def framework_env(core: Path, ini: dict) -> Env:
    var = core / "variants" / VARIANT
    cflags, cxxflags = set(read_lines(var / "cflags.txt")), set(read_lines(var / "cxxflags.txt"))
    common = cflags & cxxflags
    e = Env()
    e.process_flags(shlex.split(BOARD_EXTRA_FLAGS), ROOT)
    e.process_flags(shlex.split(ini.get("build_flags", "")), ROOT)
    e.defines.append(PLATFORMIO_MACRO)
    e.cflags += sorted(cflags - common)
    e.ccflags += sorted(common)
    e.cxxflags += sorted(cxxflags - common)
    e.defines += [d[2:].replace('\\"', '"') for d in read_lines(var / "defines.txt")]  # SCons unescapes \"
    arduino = core / "cores" / "arduino"
    e.ccflags += [f"-iprefix{arduino}", f"@{var / 'includes.txt'}", "-nostdlib"]
    e.defines += ["ARDUINO=10810", "ARDUINO_ARCH_MBED"]
    e.cpppath += [str(arduino), str(arduino / "api" / "deprecated"), str(arduino / "api" / "deprecated-avr-comp"),
                  str(var)]
    e.ccflags += BUILDER_FPU
    e.process_unflags(shlex.split(ini.get("build_unflags", "")))
    return e


def lib_env(base: Env, lib: Path, deps: list[Path]) -> Env:
    e = base.copy()
    e.cpppath = [str(lib / "src")] + [str(d) for d in deps] + e.cpppath
    manifest = lib / "library.json"
    if manifest.is_file():
        build = json.loads(manifest.read_text()).get("build", {})
        e.process_flags(build.get("flags", []), lib)
        e.process_unflags(build.get("unflags", []))
    return e


def src_filter_extra(ini: dict) -> list[Path]:
    """The files build_src_filter adds from outside src/ (the models)."""
    out = []
    for m in re.finditer(r"\+<([^>]+)>", ini.get("build_src_filter", "")):
        p = (ROOT / "firmware" / "src" / m.group(1)).resolve()  # an absolute path stays as it is
        if p.suffix in (".c", ".cpp"):
            out.append(p)  # a missing file is reported as an error of the env (compile_all)
    return out


def compile_all(jobs: list[tuple[str, Path, Env, bool]], out: Path) -> list[dict]:
    def one(job):
        group, src, env, ours = job
        obj = out / group / (src.stem + ".o")
        obj.parent.mkdir(parents=True, exist_ok=True)
        if not src.is_file():
            msg = f"{src}: error: missing (platformio.ini build_src_filter names it; `impactsense export` writes it)"
            return {"group": group, "src": src, "obj": obj, "ours": ours, "ok": False, "warnings": 0, "errors": 1,
                    "log": msg, "cmd": []}
        p = subprocess.run(env.command(src, obj), capture_output=True, text=True)
        text = p.stderr
        return {"group": group, "src": src, "obj": obj, "ours": ours, "ok": p.returncode == 0,
                "warnings": len(re.findall(r"\bwarning:", text)), "errors": len(re.findall(r"\berror:", text)),
                "log": text, "cmd": env.command(src, obj)}
    with ThreadPoolExecutor(max_workers=2) as pool:
        return list(pool.map(one, jobs))


def size_of(obj: Path) -> tuple[int, int, int]:
    p = subprocess.run(["arm-none-eabi-size", str(obj)], capture_output=True, text=True, check=True)
    t, d, b = p.stdout.splitlines()[1].split()[:3]
    return int(t), int(d), int(b)


def undefined(obj: Path) -> list[str]:
    p = subprocess.run(["arm-none-eabi-nm", "-u", str(obj)], capture_output=True, text=True, check=True)
    return [ln.split()[-1] for ln in p.stdout.splitlines() if ln.strip()]


def abi(obj: Path) -> dict:
    p = subprocess.run(["arm-none-eabi-readelf", "-A", str(obj)], capture_output=True, text=True, check=True)
    tags = dict(re.findall(r"^\s*(Tag_\w+): (.*)$", p.stdout, re.M))
    return {"fp_arch": tags.get("Tag_FP_arch"), "vfp_args": tags.get("Tag_ABI_VFP_args", "base (AAPCS)")}


def reference_abi(core: Path, out: Path) -> dict:
    """The float ABI of the variant's prebuilt archives (libcc_310_core.a: built with libmbed.a's flags)."""
    lib = core / "variants" / VARIANT / "libs" / "libcc_310_core.a"
    d = out / "ref"
    d.mkdir(parents=True, exist_ok=True)
    first = subprocess.run(["arm-none-eabi-ar", "t", str(lib)], capture_output=True, text=True,
                           check=True).stdout.split()[0]
    subprocess.run(["arm-none-eabi-ar", "x", str(lib), first], cwd=d, check=True)
    return abi(d / first)


def has_fpu_code(obj: Path) -> bool:
    p = subprocess.run(["arm-none-eabi-objdump", "-d", str(obj)], capture_output=True, text=True, check=True)
    return re.search(r"\bv(add|mul|sub|div|cvt|cmp)\w*\.f32\b", p.stdout) is not None


def framework_sources(core: Path, ble: Path) -> list[tuple[str, Path]]:
    arduino = core / "cores" / "arduino"
    srcs = [("framework", p) for p in sorted(arduino.rglob("*.cpp")) + sorted(arduino.rglob("*.c"))
            if "/mbed/" not in str(p) and "as_mbed_library" not in str(p)]
    srcs += [("framework", p) for p in sorted((core / "variants" / VARIANT).glob("*.cpp"))]
    srcs += [("ArduinoBLE", p) for p in sorted((ble / "src").rglob("*.cpp")) + sorted((ble / "src").rglob("*.c"))]
    return srcs


def build_env(name: str, core: Path, ble: Path, out: Path, framework: bool, models: Path | None = None) -> dict:
    ini = ini_env(name)
    if models is not None:  # the export's folder stands in for models/ (its include path and its C files)
        ini["build_flags"] = re.sub(r"-I\s*models\b", f"-I {models}", ini.get("build_flags", ""))
        ini["build_src_filter"] = re.sub(r"\.\./\.\./models/", f"{models}/", ini.get("build_src_filter", ""))
    base = framework_env(core, ini)
    libs = sorted(p for p in (ROOT / "firmware" / "lib").iterdir() if (p / "src").is_dir())
    lib_inc = [p / "src" for p in libs]
    ble_inc = [ble / "src"]
    jobs = []
    for lib in libs:
        env = lib_env(base, lib, [d for d in lib_inc if d != lib / "src"])
        jobs += [(lib.name, s, env, True) for s in sorted((lib / "src").glob("*.c*"))]
    src_env = base.copy()
    src_env.cpppath = [str(ROOT / "include"), str(ROOT / "firmware" / "src")] + [str(d) for d in lib_inc + ble_inc] \
        + src_env.cpppath
    jobs += [("src", s, src_env, True) for s in sorted((ROOT / "firmware" / "src").glob("*.c*"))]
    jobs += [("models", s, src_env, True) for s in src_filter_extra(ini)]
    if framework:
        fw_env = base.copy()
        fw_env.cpppath = [str(d) for d in ble_inc] + fw_env.cpppath
        jobs += [(g, s, fw_env, False) for g, s in framework_sources(core, ble)]
    return {"name": name, "results": compile_all(jobs, out / name), "env": src_env}


def report(build: dict, ref: dict, gated: bool = True) -> tuple[bool, dict]:
    """Prints one env's objects and totals; gated: the flash budget applies (the default env: the form the
    repository ships; the m2cgen env is the comparison form, built from the same export)."""
    ok = True
    name = build["name"]
    print(f"== env:{name} ==")
    ours = [r for r in build["results"] if r["ours"]]
    fw = [r for r in build["results"] if not r["ours"]]
    for r in build["results"]:
        if r["ours"] and (r["warnings"] or not r["ok"]) or (not r["ours"] and not r["ok"]):
            print(r["log"].rstrip(), file=sys.stderr)
    errors = sum(1 for r in ours if not r["ok"]) + sum(r["errors"] for r in ours)
    warnings = sum(r["warnings"] for r in ours)
    print(f"{'object':<34} {'text':>8} {'data':>6} {'bss':>7}  fp-abi / soft helpers")
    totals = {"project": [0, 0, 0], "models": [0, 0, 0], "framework": [0, 0, 0]}
    fpu_seen = False
    for r in ours:
        if not r["ok"]:
            continue
        t, d, b = size_of(r["obj"])
        key = "models" if r["group"] == "models" else "project"
        for i, v in enumerate((t, d, b)):
            totals[key][i] += v
        helpers = sorted({u for u in undefined(r["obj"]) if SOFT_HELPER.search(u)})
        a = abi(r["obj"])
        flags = []
        if helpers:
            flags.append("SOFT/DOUBLE HELPERS: " + " ".join(helpers))
            ok = False
        if a["vfp_args"] != ref["vfp_args"]:
            flags.append(f"ABI {a['vfp_args']} != variant libs' {ref['vfp_args']}")
            ok = False
        if any(INT64_TO_FLOAT.search(u) for u in undefined(r["obj"])):
            flags.append("note: __aeabi_l2f (int64 beyond 32 bits only)")
        if r["group"] == "impactcore" and has_fpu_code(r["obj"]):
            fpu_seen = True
        print(f"{r['group'] + '/' + r['src'].name:<34} {t:>8} {d:>6} {b:>7}  "
              f"{(a['fp_arch'] or '-')} {a['vfp_args']}" + ("  " + "; ".join(flags) if flags else ""))
    if not fpu_seen:
        print("impactcore has no FPU instruction: the build is not using the FPU", file=sys.stderr)
        ok = False
    fw_fail = [r for r in fw if not r["ok"]]
    for r in fw:
        if r["ok"]:
            for i, v in enumerate(size_of(r["obj"])):
                totals["framework"][i] += v
    flash = {k: v[0] + v[1] for k, v in totals.items()}
    total = flash["project"] + flash["models"]
    print(f"our code: text+data {flash['project']} B, bss {totals['project'][2]} B; models: {flash['models']} B; "
          f"ours + models {total} B of the {FLASH_BUDGET} B budget"
          + ("" if gated else f" (not gated: the shipped form is the default env's){' OVER' if total > FLASH_BUDGET else ''}"))
    if fw:
        print(f"framework units compiled: {len(fw) - len(fw_fail)}/{len(fw)} (core + variant + ArduinoBLE), "
              f"text+data {flash['framework']} B before --gc-sections, warnings {sum(r['warnings'] for r in fw)} "
              f"(theirs, not gated); libmbed.a (prebuilt) not counted")
    print(f"errors {errors}, warnings {warnings} in our units; framework errors {len(fw_fail)}")
    ok = ok and errors == 0 and warnings == 0 and not fw_fail
    if gated:
        ok = ok and total <= FLASH_BUDGET
    return ok, {"errors": errors, "warnings": warnings, "flash": flash, "framework_errors": len(fw_fail),
                "flash_gated": gated}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--core", type=Path, required=True, help="ArduinoCore-mbed checkout (cores/, variants/)")
    ap.add_argument("--ble", type=Path, required=True, help="ArduinoBLE checkout (src/)")
    ap.add_argument("--out", type=Path, default=ROOT / "build" / "board")
    ap.add_argument("--env", action="append", help="platformio.ini env (default: every nano33ble* env)")
    ap.add_argument("--no-framework", action="store_true", help="compile only our units")
    ap.add_argument("--models", type=Path, help="an export folder to compile instead of models/ (both forms)")
    ap.add_argument("--json", type=Path, help="also write the summary here")
    a = ap.parse_args(argv)
    for d, what in ((a.core / "variants" / VARIANT / "cxxflags.txt", "--core"), (a.ble / "src", "--ble")):
        if not d.exists():
            print(f"board-build: {what}: {d} not found", file=sys.stderr)
            return 2
    cp = configparser.ConfigParser(interpolation=None, inline_comment_prefixes=(";",))
    cp.read(ROOT / "platformio.ini")
    envs = a.env or [s[4:] for s in cp.sections() if s.startswith("env:nano33ble")]
    default_env = cp.get("platformio", "default_envs", fallback="nano33ble").split(",")[0].strip()
    a.out.mkdir(parents=True, exist_ok=True)
    ref = reference_abi(a.core.resolve(), a.out)
    print(f"variant prebuilt archives: {ref['fp_arch']}, float args {ref['vfp_args']}")
    all_ok, summary = True, {}
    for i, name in enumerate(envs):
        b = build_env(name, a.core.resolve(), a.ble.resolve(), a.out.resolve(), not a.no_framework and i == 0,
                      a.models.resolve() if a.models else None)
        ok, s = report(b, ref, gated=name == default_env)
        all_ok &= ok
        summary[name] = s
    if len(envs) > 1:
        print("model forms side by side (flash of the model objects, text+data):")
        for name, s in summary.items():
            print(f"  {name:<22} models {s['flash']['models']:>8} B   ours {s['flash']['project']:>8} B")
    if a.json:
        a.json.write_text(json.dumps(summary, indent=1))
    print("board-build: " + ("OK" if all_ok else "FAILED"))
    return 0 if all_ok else 1


if __name__ == "__main__":
    sys.exit(main())
