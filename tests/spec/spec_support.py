"""Harness helpers shared by the independent-reader tests (no test cases here).

Configuration (environment):
  VOXFMT_BIN            path to the `voxfmt` command-line tool
  VOXFMT_SAMPLE_WRITER  path to a program run as `WRITER OUT.h5` that writes the sphere fixture
  H5DUMP                optional, defaults to /usr/bin/h5dump
"""

import json
import os
import re
import subprocess
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
SPEC_DIR = os.path.normpath(os.path.join(HERE, "..", "..", "spec"))

VOXFMT_BIN = os.environ.get("VOXFMT_BIN", "")
SAMPLE_WRITER = os.environ.get("VOXFMT_SAMPLE_WRITER", "")
H5DUMP = os.environ.get("H5DUMP", "/usr/bin/h5dump")

TIMEOUT = 30


def _is_exe(p):
    return bool(p) and os.path.isfile(p) and os.access(p, os.X_OK)


def have_bin():
    return _is_exe(VOXFMT_BIN)


def have_writer():
    return _is_exe(SAMPLE_WRITER)


def have_h5dump():
    return _is_exe(H5DUMP)


requires_bin = unittest.skipUnless(have_bin(), "VOXFMT_BIN not set or not executable")
requires_writer = unittest.skipUnless(have_writer(), "VOXFMT_SAMPLE_WRITER not set or not executable")
requires_h5dump = unittest.skipUnless(have_h5dump(), "h5dump not found")


def run(args, timeout=TIMEOUT):
    """Run a command, capture text output. Never raises on a non-zero exit."""
    return subprocess.run([str(a) for a in args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          universal_newlines=True, timeout=timeout)


def describe(proc):
    return "command: %s\nexit: %s\nstdout:\n%s\nstderr:\n%s" % (
        " ".join(proc.args), proc.returncode, proc.stdout[-4000:], proc.stderr[-4000:])


def issue_codes():
    """{code: severity} parsed from spec/issue-codes.md."""
    codes = {}
    with open(os.path.join(SPEC_DIR, "issue-codes.md"), encoding="utf-8") as fh:
        for line in fh:
            m = re.match(r"^\|\s*`([A-Z0-9_]+)`\s*\|\s*(error|warning|info)\s*\|", line)
            if m:
                codes[m.group(1)] = m.group(2)
    if not codes:
        raise RuntimeError("no issue codes parsed from spec/issue-codes.md")
    return codes


ISSUE_CODES = issue_codes()


def same_file_name(reported, given):
    """The CLI may echo the path as given or canonicalised."""
    if reported == given:
        return True
    try:
        return os.path.realpath(reported) == os.path.realpath(given)
    except (TypeError, ValueError):
        return False


# ---------------------------------------------------------------------------------------------------------
# h5dump -H parser: {path: {"kind": GROUP|DATASET|ATTRIBUTE, "type": str, "type_lines": [...], "space": str}}
# Attribute paths are "<owner path>/<name>" ("/name" for the root group).
# ---------------------------------------------------------------------------------------------------------

_OPEN_RE = re.compile(r'^(GROUP|DATASET|ATTRIBUTE|DATATYPE|SOFTLINK|EXTERNAL_LINK) "(.*)" \{$')


def parse_h5dump(text):
    objects = {}
    stack = []  # entries: (kind, path) or ("BLOCK", None)
    current_type = None  # (path, lines) while inside a multi-line DATATYPE block

    def owner_path():
        for kind, path in reversed(stack):
            if kind in ("GROUP", "DATASET", "ATTRIBUTE"):
                return path
        return None

    for raw in text.splitlines():
        line = raw.strip()
        if not line:
            continue
        if line.startswith("HDF5 ") and line.endswith("{") and not stack:
            stack.append(("FILE", None))
            continue
        m = _OPEN_RE.match(line)
        if m:
            kind, name = m.group(1), m.group(2)
            parent = owner_path()
            if kind == "GROUP" and name == "/" and parent is None:
                path = "/"
            elif parent in (None, "/"):
                path = "/" + name
            else:
                path = parent + "/" + name
            stack.append((kind, path))
            objects[path] = {"kind": kind, "type": None, "type_lines": [], "space": None}
            continue
        if line.startswith("DATATYPE"):
            body = line[len("DATATYPE"):].strip()
            path = owner_path()
            if body.endswith("{"):
                tname = body[:-1].strip()
                stack.append(("TYPEBLOCK", path))
                current_type = path
            else:
                tname = body
            if path in objects and objects[path]["type"] is None:
                objects[path]["type"] = tname
            continue
        if line.startswith("DATASPACE"):
            path = owner_path()
            if path in objects:
                objects[path]["space"] = line[len("DATASPACE"):].strip()
            if line.count("{") > line.count("}"):
                stack.append(("BLOCK", None))
            continue
        if line == "}":
            if stack:
                kind, _ = stack.pop()
                if kind == "TYPEBLOCK":
                    current_type = None
            continue
        if current_type is not None and current_type in objects:
            objects[current_type]["type_lines"].append(line)
            continue
        if line.endswith("{"):
            stack.append(("BLOCK", None))
    return objects


def parse_json_stdout(testcase, proc):
    try:
        return json.loads(proc.stdout)
    except ValueError as exc:
        testcase.fail("stdout is not JSON (%s)\n%s" % (exc, describe(proc)))


def check_validate_json(testcase, proc, files):
    """Check the `validate --json` document shape; return {given path: file entry}."""
    js = parse_json_stdout(testcase, proc)
    testcase.assertIsInstance(js, dict, describe(proc))
    testcase.assertIn("files", js, describe(proc))
    testcase.assertIsInstance(js["files"], list, describe(proc))
    testcase.assertEqual(len(js["files"]), len(files), describe(proc))
    entries = {}
    for entry in js["files"]:
        testcase.assertIsInstance(entry, dict)
        for key in ("file", "valid", "issues"):
            testcase.assertIn(key, entry, describe(proc))
        testcase.assertIsInstance(entry["valid"], bool)
        testcase.assertIsInstance(entry["issues"], list)
        for issue in entry["issues"]:
            for key in ("code", "severity", "path", "message"):
                testcase.assertIn(key, issue, "issue lacks %r: %r" % (key, issue))
            testcase.assertRegex(issue["code"], r"^[A-Z][A-Z0-9_]*$")
            testcase.assertIn(issue["severity"], ("error", "warning", "info"))
            testcase.assertIsInstance(issue["path"], str)
            testcase.assertIsInstance(issue["message"], str)
            testcase.assertIn(issue["code"], ISSUE_CODES,
                              "issue code %r is not listed in spec/issue-codes.md" % issue["code"])
            testcase.assertEqual(issue["severity"], ISSUE_CODES[issue["code"]],
                                 "issue %r: severity differs from spec/issue-codes.md" % issue)
        has_error = any(i["severity"] == "error" for i in entry["issues"])
        testcase.assertEqual(entry["valid"], not has_error,
                             "'valid' must be true iff there is no error-severity issue: %r" % entry)
        match = [f for f in files if same_file_name(entry["file"], f)]
        testcase.assertTrue(match, "reported file %r is none of %r" % (entry["file"], files))
        entries[match[0]] = entry
    testcase.assertEqual(sorted(entries), sorted(files), describe(proc))
    return entries
