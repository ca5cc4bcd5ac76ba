import signal
import sys

from pipeline import cli

cli._cli_process[0] = True   # after a Ctrl-C, further ones are ignored until the process exits (cli._interrupted_exit)
code = cli.main()
if code == 130:   # interrupted elsewhere (a sweep's own report): ignore further Ctrl-Cs while the process ends
    signal.signal(signal.SIGINT, signal.SIG_IGN)
sys.exit(code)
