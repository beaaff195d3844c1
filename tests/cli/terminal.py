"""What a command writes on a terminal: its stderr on a pseudo-terminal (progress bars and colours are drawn on one
only)."""
import os
import subprocess


def run_on_terminal(command, **run):
    """Runs `command` with stderr on a pseudo-terminal (80 columns: the size is not set); returns the completed
    process and the bytes the terminal received."""
    master, slave = os.openpty()
    try:
        r = subprocess.run(command, stderr=slave, **run)
    finally:
        os.close(slave)
    data = b""
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:  # EIO: the terminal's other side is closed and everything was read
            break
        if not chunk:
            break
        data += chunk
    os.close(master)
    return r, data
