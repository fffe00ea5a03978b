from neoedit.cli import entry

entry()
