import signal
import sys

from pipeline.cli import main

code = main()
if code == 130 and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
    # interrupted: a further Ctrl-C while the process shuts down (stopping its compile process takes
    # seconds on a loaded machine) would end it by SIGINT instead of exit 130 (seen in CI)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
sys.exit(code)
