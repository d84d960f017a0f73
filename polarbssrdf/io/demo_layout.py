"""What a ``polarbssrdf demo`` directory holds: the names its commands write and protect.

Here, below both the demo and the commands that read a demo directory (``report``,
``evaluate``), so that neither imports the other."""

DEMO_FILE = "demo.json"
"""The demo's record of what it ran (settings, seconds)."""

DEMO_ENTRIES = ("capture", "result", "report.html", "metrics.json", DEMO_FILE, "truth_settings.json")
"""What the demo writes in OUTDIR; ``--overwrite`` removes only these."""
