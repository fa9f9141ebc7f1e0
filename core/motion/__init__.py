"""Motion data: the native clip format, motion sources' shared errors, and the motion library."""
