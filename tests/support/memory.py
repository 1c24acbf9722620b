"""Peak memory of a child interpreter, for tests that run one to measure it.

``resource.getrusage(RUSAGE_SELF).ru_maxrss`` is no good there: Linux carries a process's maximum
across fork and exec, so a child started by a pytest process that has grown to 2 GB reports at least
2 GB whatever it does.  ``VmHWM`` (/proc/self/status) is the high-water mark of the child's own
address space, which exec starts afresh.
"""

# an expression for the child's code: its peak resident memory in MB (float)
PEAK_MB = "int(open('/proc/self/status').read().split('VmHWM:')[1].split()[0]) / 1024"
