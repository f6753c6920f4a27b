"""What a rerun skips: ``setup_cache`` keeps a mesh's surfel set-up, and
``view_cache`` the false-colour views' rays, in ``files.cache_dir()``.
"""
