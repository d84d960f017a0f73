"""Importing the light packages must not import colour-science (slow, and it changes NumPy's
print options for the whole process): colour is imported by the functions that need it."""

import subprocess
import sys
import textwrap


def run_python(code):
    result = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_spectral_skin_and_calibration_do_not_import_colour():
    run_python("""
        import sys
        import numpy as np
        before = np.get_printoptions()
        import polarbssrdf.spectral, polarbssrdf.skin, polarbssrdf.calibration
        assert "colour" not in sys.modules, "colour-science imported"
        assert np.get_printoptions() == before, "NumPy print options changed"
    """)


def test_building_the_command_line_parser_does_not_import_colour():
    run_python("""
        import sys
        import polarbssrdf.cli
        polarbssrdf.cli.build_parser()
        assert "colour" not in sys.modules, "colour-science imported"
    """)


def test_colour_is_imported_when_a_function_needs_it():
    output = run_python("""
        import sys
        import numpy as np
        from polarbssrdf.spectral import default_light, sample_curve, spectral_distribution
        light = default_light()
        assert "colour" in sys.modules
        curve = spectral_distribution([400.0, 500.0, 600.0], [0.0, 1.0, 0.5])
        print(sample_curve(curve, [450.0])[0], float(sample_curve(light, [550.0])[0]) > 0)
    """)
    assert output.split() == ["0.5", "True"]
