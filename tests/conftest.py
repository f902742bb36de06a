"""Suite-wide set-up."""

import signal

# A suite started in the background (`pytest &` from a shell without job control) inherits SIGINT ignored,
# and every ``amhe`` process a test starts would inherit that too: Python then installs no Ctrl-C handler,
# and the tests that interrupt a run or a grid would see it finish instead. A handler of our own is reset
# to the default in a child at exec.
signal.signal(signal.SIGINT, signal.default_int_handler)
