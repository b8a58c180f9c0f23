"""The README's commands are what CI runs."""

import re

from tests.conftest import ROOT


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)\n```", readme, flags=re.S)
    test_cmd = next(b for b in blocks if "pytest" in b)
    ci = (ROOT / ".ci" / "run").read_text()
    assert test_cmd.strip() in ci.splitlines()


def test_every_config_file_the_readme_names_is_shipped():
    readme = (ROOT / "README.md").read_text()
    paths = set(re.findall(r"--config\s+([\w./-]+\.(?:toml|ya?ml))", readme))
    assert paths, "the README shows no --config example"
    missing = sorted(p for p in paths if not (ROOT / p).is_file())
    assert missing == []
