"""A test case with a temporary folder for the CLI's tests: `out` an asset path inside it, `write` a file there."""
import os
import tempfile
import unittest


class FolderCase(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.out = os.path.join(self.dir.name, "out.vox.h5")

    def tearDown(self):
        self.dir.cleanup()

    def write(self, name, text):
        path = os.path.join(self.dir.name, name)
        with open(path, "w") as f:
            f.write(text)
        return path
