from pointillist.console import main

main()
