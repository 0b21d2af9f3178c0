"""The Blender integration in one place: the add-on (addon/, package data that Blender runs and
mogo never imports) and `mogo blender-addon`, which writes it as the zip Blender installs
(addon_zip). The checks that run it in a real Blender are bench's (bench/blender/)."""
