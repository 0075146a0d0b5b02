"""The README's quick start: CI runs its test command verbatim; the setup script says what it needs and exits
with the documented status when it cannot install (no root, no sudo) and uses sudo when it can."""

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "setup-debian.sh"


def readme_commands():
    text = (ROOT / "README.md").read_text()
    return re.findall(r"```bash\n(.*?)\n```", text, re.S)[:2]


def test_readme_starts_with_the_two_commands_and_ci_runs_the_second():
    install_demo, install_test = readme_commands()
    assert install_demo.strip().endswith("impactsense demo") and "\n" not in install_demo.strip()
    assert "pytest" in install_test and "\n" not in install_test.strip()
    ci = [ln.strip() for ln in (ROOT / ".ci" / "run").read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    assert install_test.strip() in ci
    # Debian's system Python refuses pip outside a venv (PEP 668): both commands install into one
    for cmd in (install_demo, install_test):
        assert "python3 -m venv --system-site-packages .venv" in cmd and "python3 -m pip install" not in cmd


def fake_path(tmp_path, sudo: bool):
    """A PATH where nothing of the project's is installed, the user is not root and sudo may exist."""
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    for tool in ("bash", "sed", "env", "cat"):
        os.symlink(shutil.which(tool), bin_ / tool)
    stubs = {"id": "echo 1000", "dpkg": "exit 1", "python3": "exit 1",
             "apt-get": f'echo "apt-get $*" >> {tmp_path}/calls'}
    if sudo:
        stubs["sudo"] = f'echo "sudo $*" >> {tmp_path}/calls; "$@"'
    for name, body in stubs.items():
        (bin_ / name).write_text(f"#!{shutil.which('bash')}\n{body}\n")
        (bin_ / name).chmod(0o755)
    return str(bin_)


@pytest.mark.skipif(shutil.which("bash") is None, reason="no bash")
def test_setup_script_without_root_or_sudo_says_what_to_run(tmp_path):
    p = subprocess.run([shutil.which("bash"), str(SCRIPT), "--host"], capture_output=True, text=True,
                       env={"PATH": fake_path(tmp_path, sudo=False)})
    assert p.returncode == 3, p.stderr
    assert "not root and sudo is not installed" in p.stderr
    assert re.search(r"apt-get install .*g\+\+.*cmake.*python3-dev.*python3-venv", p.stderr)
    assert not (tmp_path / "calls").exists()


@pytest.mark.skipif(shutil.which("bash") is None, reason="no bash")
def test_setup_script_uses_sudo_and_names_the_firmware_tools(tmp_path):
    p = subprocess.run([shutil.which("bash"), str(SCRIPT)], capture_output=True, text=True,
                       env={"PATH": fake_path(tmp_path, sudo=True)})
    assert p.returncode == 0, p.stderr
    calls = (tmp_path / "calls").read_text()
    assert "sudo apt-get update" in calls and "qemu-system-arm" in calls and "gcc-arm-none-eabi" in calls
    bad = subprocess.run([shutil.which("bash"), str(SCRIPT), "--nonsense"], capture_output=True, text=True)
    assert bad.returncode == 2


def test_progress_bars_stay_out_of_log_files():
    import io

    from impactsense.progress import progress_bar

    log = io.StringIO()  # a file or a pipe: not a terminal
    with progress_bar(total=50, file=log) as bar:
        bar.update(50)
    assert log.getvalue() == ""

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    term = Terminal()
    with progress_bar(total=50, file=term, mininterval=0) as bar:
        bar.update(50)
    assert "\r" in term.getvalue() and "50/50" in term.getvalue()
    quiet = Terminal()
    with progress_bar(False, total=5, file=quiet) as bar:
        bar.update(5)
    assert quiet.getvalue() == ""
