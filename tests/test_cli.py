"""The ``polarbssrdf`` command line as a whole: --version, Ctrl-C, plugin errors."""

import signal
import subprocess
import sys
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi
import pytest

import polarbssrdf
from helpers import default_sigint
from polarbssrdf.cli import main
from polarbssrdf.errors import CommandError, is_plugin_error, plugin_error_message

REPO = Path(__file__).resolve().parents[1]
SPHERE = REPO / "scenes" / "sphere.xml"

# What Mitsuba 3.9 raises when a Python plugin's constructor raises (abridged paths).
MITSUBA_PLUGIN_ERROR = (
    '[parser.cpp:1718] At scene.xml (line 53, col 10): failed to instantiate bsdf plugin of '
    'type "pbssrdf": Traceback (most recent call last):\n'
    '  File "/work/main/polarbssrdf/registration.py", line 19, in <lambda>\n'
    '  File "/work/main/plugins/pbssrdf.py", line 146, in __init__\n'
    '  File "/work/main/plugins/pbssrdf.py", line 94, in check\n'
    "ValueError: pbssrdf: parameter 'rho_sss' = 1.7 is outside its valid range [0, 1]\n")


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out == (f"polarbssrdf {polarbssrdf.__version__} (Mitsuba {mi.__version__}, "
                   f"Dr.Jit {dr.__version__})\n")


def test_version_of_the_console_command_is_fast():
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "polarbssrdf", "--version"],
                            capture_output=True, text=True, timeout=60)
    seconds = time.perf_counter() - start
    assert result.returncode == 0 and result.stdout.startswith(
        f"polarbssrdf {polarbssrdf.__version__} ")
    assert seconds < 10  # about 0.3 s: Mitsuba is imported with the package anyway


def interrupt(*args, **kwargs):
    raise KeyboardInterrupt


@pytest.mark.parametrize("argv, message", [
    (["render", "scene.xml", "out"], "polarbssrdf render: interrupted\n"),
    (["synth", "out"], "polarbssrdf synth: interrupted; rerun with --resume to continue\n"),
])
def test_ctrl_c_prints_one_line_and_exits_130(monkeypatch, capsys, argv, message):
    module = {"render": "polarbssrdf.render.commands",
              "synth": "polarbssrdf.synth.commands"}[argv[0]]
    monkeypatch.setattr(f"{module}.run", interrupt)
    assert main(argv) == 130
    captured = capsys.readouterr()
    assert captured.err == message and captured.out == ""


def test_ctrl_c_inside_an_import_is_still_an_interrupt(monkeypatch, capsys):
    """Ctrl-C during mi.set_variant surfaces as a SystemError caused by KeyboardInterrupt."""
    def interrupted_import(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as error:
            raise SystemError("<built-in function __import__> returned a result with an "
                              "exception set") from error

    monkeypatch.setattr("polarbssrdf.render.commands.run", interrupted_import)
    assert main(["render", "scene.xml", "out"]) == 130
    assert capsys.readouterr().err == "polarbssrdf render: interrupted\n"


def test_ctrl_c_inside_a_python_plugin_is_still_an_interrupt(monkeypatch, capsys):
    """Mitsuba turns a KeyboardInterrupt in a Python plugin's constructor into a plugin error."""
    mi.set_variant("scalar_rgb")

    class Interrupted(mi.BSDF):
        def __init__(self, props):
            raise KeyboardInterrupt

    class Refusing(mi.BSDF):
        def __init__(self, props):
            raise ValueError("refusing: parameter out of range")

    mi.register_bsdf("test_interrupted", Interrupted)
    mi.register_bsdf("test_refusing", Refusing)
    errors = {}
    for name in ("test_interrupted", "test_refusing"):
        try:
            mi.load_dict({"type": name})
        except RuntimeError as error:
            errors[name] = error
    assert is_plugin_error(errors["test_interrupted"]) and is_plugin_error(errors["test_refusing"])

    def run(args):
        raise errors["test_interrupted"]

    monkeypatch.setattr("polarbssrdf.render.commands.run", run)
    assert main(["render", "scene.xml", "out"]) == 130
    assert capsys.readouterr().err == "polarbssrdf render: interrupted\n"

    def refuse(args):
        raise errors["test_refusing"]

    monkeypatch.setattr("polarbssrdf.render.commands.run", refuse)
    assert main(["render", "scene.xml", "out"]) == 2  # a plugin's own error stays an error
    assert "refusing: parameter out of range" in capsys.readouterr().err


def test_ctrl_c_is_not_reported_as_the_error_it_caused(monkeypatch, capsys):
    """A CommandError raised while handling Ctrl-C (e.g. "cannot activate variant") is Ctrl-C."""
    def interrupted_variant(args):
        try:
            raise ImportError("Encountered an error while initializing the extension.") \
                from KeyboardInterrupt()
        except ImportError as error:
            raise CommandError(f"cannot activate Mitsuba variant: {error}") from None

    monkeypatch.setattr("polarbssrdf.render.commands.run", interrupted_variant)
    assert main(["render", "scene.xml", "out"]) == 130
    assert capsys.readouterr().err == "polarbssrdf render: interrupted\n"


def test_ctrl_c_while_writing_leaves_no_partial_file(monkeypatch, capsys, tmp_path):
    """Interrupted in the middle of writing a preview: no temporary or half-written file."""
    import polarbssrdf.io.atomic as atomic

    real_fsync, calls = atomic._fsync_file, []

    def fsync_then_interrupt(path):
        calls.append(path)
        if len(calls) == 3:  # polarization.exr and I0.png are done; I45.png is not
            raise KeyboardInterrupt
        real_fsync(path)

    monkeypatch.setattr(atomic, "_fsync_file", fsync_then_interrupt)
    outdir = tmp_path / "out"
    status = main(["render", str(SPHERE), str(outdir), "-D", "resolution=8", "-D", "spp=1"])
    assert status == 130
    assert capsys.readouterr().err == "polarbssrdf render: interrupted\n"
    assert sorted(p.name for p in outdir.iterdir()) == ["I0.png", "polarization.exr"]


def variant_loaded(pid: int, variant: str) -> bool:
    """Whether process ``pid`` has loaded the Mitsuba variant's extension module."""
    try:
        return f"{variant}.cpython" in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


def test_sigint_to_a_running_render(tmp_path):
    """A real Ctrl-C (SIGINT) while ``polarbssrdf render`` runs: status 130, one line, no file.

    The signal is sent once the command has loaded its Mitsuba variant (in
    ``render``'s own code, after start-up), seen in ``/proc/<pid>/maps``.
    """
    if not Path("/proc/self/maps").exists():
        pytest.skip("needs /proc to see when the render has started")
    script = Path(sys.executable).parent / "polarbssrdf"
    launcher = [str(script)] if script.exists() else [sys.executable, "-m", "polarbssrdf"]
    outdir = tmp_path / "out"
    child = subprocess.Popen([*launcher, "render", str(SPHERE), str(outdir), "-D",
                              "resolution=256", "-D", "spp=256"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             preexec_fn=default_sigint)
    try:
        deadline = time.monotonic() + 15
        while not variant_loaded(child.pid, "llvm_ad_mono_polarized"):
            if child.poll() is not None or time.monotonic() > deadline:
                pytest.skip("could not catch the render while it was running")
            time.sleep(0.02)
        child.send_signal(signal.SIGINT)
        out, err = child.communicate(timeout=30)
    finally:
        child.kill()
    if child.returncode == 0:
        pytest.skip("the render finished before the interrupt arrived")
    assert child.returncode == 130, err
    assert "Traceback" not in err
    # Mitsuba may log its own "Received interrupt signal" warning first.
    assert err.splitlines()[-1] == "polarbssrdf render: interrupted"
    if outdir.exists():
        assert not [p for p in outdir.iterdir() if p.name.startswith(".")]
        assert not (outdir / "render.json").exists()


def terminate_myself(args):
    import os

    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(10)  # the handler raises here
    raise AssertionError("SIGTERM did not stop the command")


def test_sigterm_stops_like_ctrl_c_with_status_143(monkeypatch, capsys):
    """Issue 32, item 10: SIGTERM exited 143 without the line Ctrl-C prints."""
    monkeypatch.setattr("polarbssrdf.synth.commands.run", terminate_myself)
    before = signal.getsignal(signal.SIGTERM)
    assert main(["synth", "out"]) == 128 + signal.SIGTERM
    captured = capsys.readouterr()
    assert captured.err == ("polarbssrdf synth: interrupted (SIGTERM); rerun with --resume to "
                            "continue\n")
    assert signal.getsignal(signal.SIGTERM) is before  # main() leaves the handler as it was


def test_sigterm_to_a_running_synth(tmp_path):
    """A real SIGTERM while ``polarbssrdf synth`` renders: status 143, the resume line."""
    if not Path("/proc/self/maps").exists():
        pytest.skip("needs /proc to see when the render has started")
    script = Path(sys.executable).parent / "polarbssrdf"
    launcher = [str(script)] if script.exists() else [sys.executable, "-m", "polarbssrdf"]
    child = subprocess.Popen([*launcher, "synth", str(tmp_path / "capture"), "--object",
                              "sphere", "--views", "4", "--resolution", "256", "--texture",
                              "32", "--spp", "64", "--quiet"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 15
        while not variant_loaded(child.pid, "llvm_ad_mono_polarized"):
            if child.poll() is not None or time.monotonic() > deadline:
                pytest.skip("could not catch synth while it was running")
            time.sleep(0.02)
        child.send_signal(signal.SIGTERM)
        out, err = child.communicate(timeout=60)
    finally:
        child.kill()
    if child.returncode == 0:
        pytest.skip("synth finished before the signal arrived")
    assert child.returncode == 143, err
    assert "Traceback" not in err
    assert err.splitlines()[-1] == ("polarbssrdf synth: interrupted (SIGTERM); rerun with "
                                    "--resume to continue")


def test_plugin_error_message_keeps_context_and_the_plugin_message():
    message = plugin_error_message(RuntimeError(MITSUBA_PLUGIN_ERROR))
    assert message == ('At scene.xml (line 53, col 10): failed to instantiate bsdf plugin of '
                       'type "pbssrdf": pbssrdf: parameter \'rho_sss\' = 1.7 is outside its '
                       'valid range [0, 1]')
    assert is_plugin_error(RuntimeError(MITSUBA_PLUGIN_ERROR))


def test_plugin_error_message_of_other_errors():
    bug = MITSUBA_PLUGIN_ERROR.replace("ValueError: pbssrdf: parameter", "AttributeError: x")
    assert plugin_error_message(RuntimeError(bug)).endswith(
        'type "pbssrdf": AttributeError: x \'rho_sss\' = 1.7 is outside its valid range [0, 1]')
    plain = RuntimeError('[parser.cpp:451] Error while loading a.xml (line 36, col 14): '
                         'could not parse integer value "abc"')
    assert not is_plugin_error(plain) and not is_plugin_error(CommandError("x"))
    assert plugin_error_message(plain) == ('Error while loading a.xml (line 36, col 14): '
                                           'could not parse integer value "abc"')


def test_cli_turns_plugin_errors_from_any_command_into_one_line(monkeypatch, capsys):
    """E.g. synth builds scenes with mi.load_dict: a plugin's error is printed, not raised."""
    def failing_run(args):
        raise RuntimeError(MITSUBA_PLUGIN_ERROR)

    monkeypatch.setattr("polarbssrdf.synth.commands.run", failing_run)
    assert main(["synth", "out"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("polarbssrdf synth: error: At scene.xml (line 53, col 10)")


def test_other_runtime_errors_still_raise(monkeypatch):
    def failing_run(args):
        raise RuntimeError("a bug")

    monkeypatch.setattr("polarbssrdf.render.commands.run", failing_run)
    with pytest.raises(RuntimeError, match="a bug"):
        main(["render", "scene.xml", "out"])
