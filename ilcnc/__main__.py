"""``python -m ilcnc`` entry point."""

from ilcnc.cli import main

if __name__ == "__main__":
    main()
