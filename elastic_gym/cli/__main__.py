"""``python -m elastic_gym.cli``."""

import sys

from elastic_gym.cli import main

sys.exit(main())
