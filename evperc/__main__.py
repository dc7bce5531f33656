from evperc.cli import main

main()
