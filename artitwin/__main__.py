from artitwin.cli import main

main()
