from heoslice.cli import main

main()
