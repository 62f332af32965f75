from zsbfm.cli import main

main()
