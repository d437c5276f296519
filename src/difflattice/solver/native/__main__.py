"""`python -m difflattice.solver.native`: build (or find) the native CPU kernels for this machine
ahead of time, e.g. after `pip install` or in an image; prints the library's path (`build.main`)."""

from .build import main

raise SystemExit(main())
