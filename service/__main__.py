"""``python -m service`` = the ``depthview`` command."""

from service.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
