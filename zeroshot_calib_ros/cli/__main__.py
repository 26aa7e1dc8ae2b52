"""``python -m zeroshot_calib_ros.cli``: the zeroshot-calib command."""
import sys

from .command import main

sys.exit(main())
