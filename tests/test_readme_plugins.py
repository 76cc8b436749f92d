"""README's table of the model plugins is what their folders declare (scripts/readme_plugins.py writes it)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_readmes_table_of_the_model_plugins_is_current_with_each_folder_once():
    done = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "readme_plugins.py"), "--check"], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stdout + done.stderr
    readme = (ROOT / "README.md").read_text()
    table = readme[
        readme.index("<!-- scripts/readme_plugins.py writes") : readme.index("<!-- end of scripts/readme_plugins.py")
    ]
    rows = re.findall(r"^\| \[`plugins/(\w+)`\]", table, flags=re.M)
    folders = sorted(p.name for p in (ROOT / "plugins").iterdir() if (p / "pyproject.toml").is_file())
    assert rows == folders  # each plugin folder once, and no row without its folder
