"""``python -m pcdof``: the ``pcdof`` command."""

import pcdof_console

pcdof_console.main()
