"""`python -m flocklab …`: the `flocklab` command."""

import sys

from flocklab.service.entry import main

sys.exit(main())
