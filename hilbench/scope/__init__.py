"""A live scope in the browser (and the same viewer for recordings): see hilbench.scope.server."""
