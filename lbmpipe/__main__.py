"""``python -m lbmpipe`` == the ``lbmpipe`` console script."""

from lbmpipe.cli import main

if __name__ == "__main__":
    main()
