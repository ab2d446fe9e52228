"""``python -m dcsms_ros.cli`` == ``dcsms`` (handy before the package is installed)."""

import sys

from dcsms_ros.cli import main

sys.exit(main())
