from gazepipe.cli.main import main

main()
