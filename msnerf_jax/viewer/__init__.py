"""The interactive viewer (`msnerf view`): a run's scene in the browser, through viser.

  * `camera`: the browser's camera (viser's OpenCV pose and vertical field of view) as a
    library camera, training views as browser poses, frame sizes;
  * `frames`: what one frame is (camera, style, level) and rendering it from a loaded run;
  * `scheduler`: progressive, latest-wins rendering shared fairly by every client;
  * `server`: the viser page (GUI, uploads, saving) on top of them;
  * `probe`: a headless client speaking viser's protocol (tests, load and speed scripts).

viser is installed with the package (the viewer is a main feature); only this package
imports it.
"""
