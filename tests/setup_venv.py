#!/usr/bin/env python3
"""Creates tests/reference/.venv with the pinned reference readers, reinstalling only
when requirements.txt changed."""
import hashlib
import os
import subprocess
import sys
import venv

HERE = os.path.dirname(os.path.abspath(__file__))
VENV = os.path.join(HERE, "reference", ".venv")
REQ = os.path.join(HERE, "reference", "requirements.txt")
STAMP = os.path.join(VENV, ".requirements.sha256")

digest = hashlib.sha256(open(REQ, "rb").read()).hexdigest()
if os.path.exists(STAMP) and open(STAMP).read() == digest:
    sys.exit(0)
if not os.path.exists(os.path.join(VENV, "bin", "python")):
    venv.create(VENV, with_pip=True)
py = os.path.join(VENV, "bin", "python")
subprocess.run([py, "-m", "pip", "install", "-q", "--disable-pip-version-check", "-r", REQ], check=True)
with open(STAMP, "w") as f:
    f.write(digest)
