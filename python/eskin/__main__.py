from eskin.cli import main

main()
