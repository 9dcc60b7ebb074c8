from rwlab.cli import main

main()
