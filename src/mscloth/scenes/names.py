"""The built-in scenes' names, without importing Mitsuba (``mscloth --help`` lists them)."""

#: In the order ``mscloth`` lists them; :data:`.builtin.SCENES` holds one builder for each.
SCENE_NAMES = ("swatch", "plane", "sphere", "drape", "satin", "satin-plane", "denim")
